"""``quadslam sweep``: specs, job resolution, the Ray driver, the table and its plots."""
