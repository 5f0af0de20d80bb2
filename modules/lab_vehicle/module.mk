# lab_vehicle: the in-lab twin vehicle (route follower, stop / proceed state machine) -> POSE.
$(eval $(call c_program,lab_vehicle,modules/lab_vehicle))
$(eval $(call c_test,test_lab_vehicle,tests/c/test_lab_vehicle.c modules/lab_vehicle/lab_vehicle.c modules/lab_vehicle/lv_plan.c))
