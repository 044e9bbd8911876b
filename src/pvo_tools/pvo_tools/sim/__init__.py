"""`pvo sim`: a rendered synthetic world (MuJoCo) with a stereo rig under the real sun, IMU, GPS and truth."""
