"""semslam as a ROS 1 node (``semslam ros``): live messages decoded by the same rosbags decoders as the bag
reader, the SLAM estimate published in ROS frames. rospy is imported only by :mod:`semslam.run.ros1.node`;
the rest of this package (conversions, decoding, timing) works without ROS. See docs/ros1.md."""
