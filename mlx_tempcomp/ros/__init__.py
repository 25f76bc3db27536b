"""Thin ROS 2 nodes that translate parameters and messages to core objects."""
