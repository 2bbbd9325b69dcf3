"""Radiometry: an echo's range, incidence, backscatter and reflectance, and a flight's calibration.

    equations.py  the radar equation's values, trajectories and time systems, incidence, calibration samples
    flight.py     a file's part: its trajectory checked against its pulses, a range's radiometry, a reference patch

Nothing is imported here: import the module you need.
"""
