"""Raw data sources: simulated and SPI sensors, rosbag2 replay. No rclpy."""
