# simdrive: a simulated study site and drive (LiDAR, IMU, CAN, GNSS, ground truth) -> LCM log.
# With --scenario it stages agents through the director's core (hence -lccd).
$(eval $(call c_program,simdrive,tools/simdrive modules/director/core,-lccd))
$(OBJ)/tools/simdrive/occlusion_truth.o: CPPFLAGS += -I$(TOP)/modules/director/core
