"""The simulated world of B lanes: the true vehicle, its IMU and LiDAR, the wind, the landmark
map, the reference trajectory, the per-episode randomisation and the injected faults
(docs/design.md §3, §9). Everything here may see the truth; nothing here estimates."""
