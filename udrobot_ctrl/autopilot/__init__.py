"""The vehicle's own flight controller, as data plus one implementation (ArduSub 4.1-4.5).

``motors``: ArduSub's output side (AP_Motors6DOF frame factors, motor directions, PWM range, battery
compensation) from the mixer inputs to the thrusters' PWM, and back. The controllers (attitude angle P ->
rate PID, depth hold on AC_PosControl z, the flight modes and pilot input shaping) use it; ``simulate
--closed-loop`` and the diagnoser's closed-loop replays fly the plant under them.
"""
