"""semslam.segmentation"""
