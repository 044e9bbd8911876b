"""pvo stereo VO frontend: the ROS-free pipeline in :mod:`pvo_frontend.vo` and the ``stereo_vo`` node."""
