"""The export targets, in a module that imports nothing (``vesselid export --help`` lists them)."""

#: Export targets of ``vesselid export --to``.
FORMATS = ("vrx", "pvs", "ardupilot", "ros2")
