"""Temperature-compensated angular rate for MLX90609-class gyros."""
