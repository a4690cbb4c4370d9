"""The equations of motion, thrusters and integrators (one definition of the dynamics)."""
