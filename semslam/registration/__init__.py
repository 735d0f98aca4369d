"""semslam.registration"""
