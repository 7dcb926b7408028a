"""Files for people and other tools: the one-page report and the ROS exports."""
