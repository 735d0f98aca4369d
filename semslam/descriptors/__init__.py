"""semslam.descriptors"""
