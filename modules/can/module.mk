# modules/can: SocketCAN / candump / CAN_FRAME replay -> CAN_FRAME + VEHICLE_SPEED.
$(eval $(call c_program,can,modules/can))
