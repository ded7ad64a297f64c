"""Simulated 2-link SCARA, scripted human hand and scripted demonstrator."""
