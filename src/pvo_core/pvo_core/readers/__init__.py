"""Dataset readers: KITTI odometry (+ sun CSVs), the KITTI raw-derived KLT tracks, the simulator's IMU/GPS
sidecars, the viso2-s results and the Devon Island rover navigation dataset."""

from .corpus import CorpusManifest, CorpusSequence, read_corpus_manifest
from .devon import DevonDataset, SunSensorReading, read_devon_sun_sensor, read_devon_sun_sensor_sampled
from .kitti import KittiSequence, read_kitti_calibration, read_kitti_sun_csv, read_kitti_times
from .klt_tracks import KLTTracks, read_klt_tracks
from .sidecars import (
    ROTATION_PREDICTIONS_HEADER,
    SUN_PREDICTIONS_HEADER,
    imu_at_stamps,
    read_gps_csv,
    read_imu_csv,
    read_rotation_predictions_csv,
    read_sun_predictions_csv,
)
from .viso2s import (
    SEQUENCE_DRIVES,
    KittiSunSequence,
    Viso2sRun,
    read_kitti_sun_sequence,
    read_viso2s,
    read_viso2s_sequence,
    viso2s_path,
)

__all__ = [
    "ROTATION_PREDICTIONS_HEADER",
    "SEQUENCE_DRIVES",
    "SUN_PREDICTIONS_HEADER",
    "CorpusManifest",
    "CorpusSequence",
    "DevonDataset",
    "KLTTracks",
    "KittiSequence",
    "KittiSunSequence",
    "SunSensorReading",
    "Viso2sRun",
    "imu_at_stamps",
    "read_corpus_manifest",
    "read_devon_sun_sensor",
    "read_devon_sun_sensor_sampled",
    "read_gps_csv",
    "read_imu_csv",
    "read_kitti_calibration",
    "read_kitti_sun_csv",
    "read_kitti_sun_sequence",
    "read_kitti_times",
    "read_klt_tracks",
    "read_rotation_predictions_csv",
    "read_sun_predictions_csv",
    "read_viso2s",
    "read_viso2s_sequence",
    "viso2s_path",
]
