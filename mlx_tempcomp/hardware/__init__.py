"""Hardware I/O: SPI transports and device protocols. Nothing here imports rclpy."""
