"""Hand and object models: kinematics, geometry, surface samples and signed distance fields."""
