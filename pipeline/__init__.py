"""pipeline: the Beam layer and the command line over fwcore."""
