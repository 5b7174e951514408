"""crowdteleop: crowdsourced robot teleoperation on simulated arms (after RoboTurk, CoRL 2018)."""

__version__ = "0.1.0"
