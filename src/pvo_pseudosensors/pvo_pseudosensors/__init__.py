"""pvo_pseudosensors: learned and simulated pseudo-sensors as ROS-free modules plus one node each."""
