"""What a waveform says of the forest, for every sensor: the ground (the lowest mode), RH0..RH100 from the
cumulative energy above it (GEDI L2A), and canopy cover, PAI and the vertical profile from the canopy and ground
energies (GEDI L2B).

    signal.py    smoothing, the noise thresholds and the signal's extent (toploc, botloc)
    ground.py    the modes and the ground: the lowest, or L2A's mode selection (algorithm 2)
    algorithms.py  GEDI L2A's six algorithms as data, and which one each shot takes
    rh.py        RH0..RH100
    canopy.py    rv, rg, Pgap, cover, PAI, PAVD
    waveform.py  the settings and the batch: every pulse's metrics in one call (kernel.py: its numba kernel)
    pulses.py    a PulseBatch's metrics, whatever the sensor
    lvis.py      LVIS's own Level 2 metrics (ZG, ZH, RH) on LVIS files
    footprint.py a large footprint's waveform built from small ones (GEDI from the air)
    biomass.py   aboveground biomass density from RH by GEDI L4A's models (their table: data/l4a_models.json)
"""
