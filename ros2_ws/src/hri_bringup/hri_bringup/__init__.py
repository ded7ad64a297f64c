"""Starting the HRI nodes as `ros2 run` processes, and the `system` node of the live loop."""
