"""Thin rclpy shells around train_localization.core."""
