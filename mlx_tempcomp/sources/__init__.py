"""Sample sources of the driver: simulated and SPI parts, their protocol, decimation. No rclpy."""
