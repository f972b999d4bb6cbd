"""rosbag2 MCAP bags: layout, writer, readers, fast columns, recovery, the run record."""
