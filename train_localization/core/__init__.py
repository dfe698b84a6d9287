"""Functional core: pure Python + numpy + filterpy. Nothing below imports rclpy."""
