# modules/can: SocketCAN / candump / CAN_FRAME replay -> CAN_FRAME + VEHICLE_SPEED.
$(eval $(call c_program,can,modules/can))
CAN_CORE := modules/can/can_dbc.c modules/can/can_speed.c modules/can/can_kernel.c
$(eval $(call c_test,test_can,modules/can/test/test_can.c $(CAN_CORE)))
# Not a unit test (no test_ prefix): tests/test_can.py compares its output with cantools.
$(eval $(call c_test,can_signal_dump,modules/can/test/can_signal_dump.c $(CAN_CORE)))
# Benchmark helper (no test_ prefix: not a unit test); `make bench-can` prints the table.
$(eval $(call c_test,can_bench,modules/can/test/can_bench.c $(CAN_CORE)))
BENCH_TARGETS += bench-can
.PHONY: bench-can
bench-can: $(BIN)/can $(BUILD)/tests/can_bench
	@$(VPY) modules/can/bench_can.py
