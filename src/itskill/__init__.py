"""itskill: task-oriented adaptive learning of robot manipulation skills."""

__version__ = "0.1.0"
