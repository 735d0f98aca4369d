"""semslam.simulation"""
