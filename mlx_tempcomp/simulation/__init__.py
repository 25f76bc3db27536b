"""Simulated sensors: physics models and frame-level simulated devices (no rclpy)."""
