"""autopilot stage."""
