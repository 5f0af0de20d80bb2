# lab_vehicle: the in-lab twin vehicle (route follower, stop / proceed state machine) -> POSE.
$(eval $(call c_program,lab_vehicle,modules/lab_vehicle))
