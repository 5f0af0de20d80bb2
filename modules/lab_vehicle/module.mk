# lab_vehicle: the in-lab twin vehicle (route follower, stop / proceed state machine) -> POSE.
$(eval $(call c_program,lab_vehicle,modules/lab_vehicle modules/lab_vehicle/core))
$(eval $(call c_test,test_lab_vehicle,tests/c/test_lab_vehicle.c $(call dir_c,modules/lab_vehicle/core)))
