"""Radiometry: an echo's range, incidence, backscatter and reflectance, and a flight's calibration.

    equations.py  the radar equation's values: range, incidence, cross-section, reflectance, calibration samples
    trajectory.py the platform's trajectory (CSV, SBET) and GPS time systems, checked against a file's pulses
    errors.py     RadiometryError, naming the file and the fix
    flight.py     a file's part: its trajectory checked against its pulses, a range's radiometry, a reference patch

Nothing is imported here: import the module you need.
"""
