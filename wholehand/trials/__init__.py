"""Trials: a grasp set up in a backend, held through a perturbation protocol, and its outcome."""
