"""Time: poses and odometry, 4D volume alignment, cross-volume id stitching and tracking."""
