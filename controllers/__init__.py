"""Feedback and feedforward controllers, and how the feedforwards are identified."""
