"""Dataset readers: KITTI odometry (+ sun CSVs), the simulator's IMU/GPS sidecars, the viso2-s
results and the Devon Island rover navigation dataset."""

from .devon import DevonDataset, SunSensorReading, read_devon_sun_sensor, read_devon_sun_sensor_sampled
from .kitti import KittiSequence, read_kitti_calibration, read_kitti_sun_csv, read_kitti_times
from .sidecars import read_gps_csv, read_imu_csv

__all__ = [
    "DevonDataset",
    "KittiSequence",
    "SunSensorReading",
    "read_devon_sun_sensor",
    "read_devon_sun_sensor_sampled",
    "read_gps_csv",
    "read_imu_csv",
    "read_kitti_calibration",
    "read_kitti_sun_csv",
    "read_kitti_times",
]
