"""The control loop: observations, commands, stages, observers and filters, run records."""
