"""Control design on the plant: linearisation, LQR, PID, MPC, EKF, missions, metrics, compare."""
