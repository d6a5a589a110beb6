"""The control loop: stages, observers, observation filters, grasp-loss checks and run records."""
