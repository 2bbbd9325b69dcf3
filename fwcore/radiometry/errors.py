"""The one error of radiometry: a trajectory, a reference patch or an option the run cannot use."""

from __future__ import annotations


class RadiometryError(ValueError):
    """A trajectory, a reference patch or an option the run cannot use; the message names the file and the fix."""
