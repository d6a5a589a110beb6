"""Object descriptions shipped with wholehand (YCB registry, procedural shapes, grasps)."""
