"""What the HRI packages share: the SCARA model, the task potential and files, ROS helpers."""
