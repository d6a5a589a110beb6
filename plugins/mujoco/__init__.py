"""The MuJoCo plug-in: the simulation backend (``backend``) and the MuJoCo models it builds.

``scene`` builds the hand-object scene from a hand's URDF (``hand_spec``), an object's convex
parts (``object_spec``) and the scene's options (``scene_options``); ``contacts`` reads the
ground-truth contacts and warnings; ``step_guard`` retries a step that would diverge; ``poses``
converts poses. The ``mink`` reacher builds its IK model from the same parts.
"""
