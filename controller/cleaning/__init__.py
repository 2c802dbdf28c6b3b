"""The pond-cleaning robot: pond geometry, coverage plan, coverage map, steering, state machine."""
