"""semslam.io"""
