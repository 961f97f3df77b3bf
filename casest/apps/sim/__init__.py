"""Simulators of the bundled examples: the calibration flight (paper Sec. IV) and the 6-DOF
aircraft with the coefficient model of summary Sec. 6."""
