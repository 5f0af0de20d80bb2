# modules/can: SocketCAN / candump / CAN_FRAME replay -> CAN_FRAME + VEHICLE_SPEED.
# core/ is pure (DBC reader, speed decoding, kernel frame conversion); main.c and
# can_socket.c are the shell.
CAN_CORE := $(call dir_c,modules/can/core)
$(eval $(call c_program,can,modules/can modules/can/core))
$(eval $(call c_test,test_can,tests/c/test_can.c $(CAN_CORE)))
# Not a unit test (no test_ prefix): tests/test_can.py compares its output with cantools.
$(eval $(call c_test,can_signal_dump,tests/c/can_signal_dump.c $(CAN_CORE)))
# Benchmark helper (no test_ prefix: not a unit test); `make bench-can` prints the table.
$(eval $(call c_test,can_bench,modules/can/bench/can_bench.c $(CAN_CORE)))
BENCH_TARGETS += bench-can
.PHONY: bench-can
bench-can: $(BIN)/can $(BUILD)/tests/can_bench
	@$(VPY) modules/can/bench/bench_can.py
