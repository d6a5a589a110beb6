"""The control loop: one force-regulation cycle, the scheduler over a backend, run records."""
