"""semslam.slam"""
