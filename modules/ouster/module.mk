# ouster: Ouster lidar/IMU UDP driver (docs/ouster.md).
$(eval $(call c_program,ouster,modules/ouster,-lcjson))
# ouster-points: LIDAR_SCAN points through common/pb_scan as CSV (checks xyz against references).
$(eval $(call c_program,ouster-points,modules/ouster/points))
