"""pvo_core: the ROS-free core of pvo (pseudo-sensor visual odometry).

Lie groups (:mod:`.lie`), the stereo camera (:mod:`.camera`), covariance conversion
(:mod:`.covariance`), sun-direction angles (:mod:`.sun`), trajectories (:mod:`.trajectory`) and
dataset readers (:mod:`.readers`). No module here imports rclpy.
"""

__version__ = "0.1.0"
