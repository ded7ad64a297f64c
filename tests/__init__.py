"""Topic-level integration tests: real node processes started with `ros2 run`."""
