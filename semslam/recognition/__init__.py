"""semslam.recognition"""
