"""The project's stand-in for ros2cli: `ros2 run`, `ros2 topic` and `ros2 bag`."""
