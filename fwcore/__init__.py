"""fwcore: the numeric core of full-waveform LiDAR decomposition (no Beam here)."""

__version__ = "0.1.0"
