"""Grasps: the stored-grasp file format and the MuJoCo grasp generator."""
