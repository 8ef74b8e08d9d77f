"""Lightweight kinematic multi-robot simulator standing in for Nav2.

Importing ``sim`` never imports ROS or SUMO; their adapters live in their own modules.
"""
