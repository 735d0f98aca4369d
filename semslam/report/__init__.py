"""semslam.report"""
