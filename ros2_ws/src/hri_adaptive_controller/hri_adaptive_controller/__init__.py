"""Event-based task switching and the adaptive HRI torque controller."""
