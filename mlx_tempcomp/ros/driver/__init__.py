"""
The driver node: raw rate and temperature from a part or a bag, on the raw topics.

By module: `timed_stream` (the sampling schedule every part shares, `StreamPorts`, the
device stream's base), one stream per part (`mlx90609_stream`, `adis16130_stream`,
`mpu6000_stream`: the part opened from the settings, its reads, its service),
`bag_replay` (``source: bag``: a rosbag2 folder replayed on the same topics), `node`
(`DriverNode`, `STREAMS`: the stream of each ``device``; the executable's `main`).
"""
