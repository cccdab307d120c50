"""pybullet helpers: headless clients, static boxes, the Panda arm (checks and IK)."""
