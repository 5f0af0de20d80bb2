# simdrive: a simulated study site and drive (LiDAR, IMU, CAN, GNSS, ground truth) -> LCM log.
$(eval $(call c_program,simdrive,tools/simdrive))
