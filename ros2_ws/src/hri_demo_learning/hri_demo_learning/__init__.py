"""Learning HRI tasks from demonstration: rosbag2 recorder and learner."""
