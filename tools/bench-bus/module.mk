# bench-bus: 10 minutes of the car's message load on the live bus under the supervisor
# (recorder, localizer, lab_vehicle, log-summary): nothing lost, memory flat. BENCH_BUS_ARGS=--duration 60 for a short run.
BENCH_TARGETS += bench-bus
.PHONY: bench-bus
bench-bus: $(BIN)/supervisor $(BIN)/localizer $(BIN)/lab_vehicle $(BIN)/log-summary $(BIN)/simdrive maps
	@$(VPY) tools/bench-bus/bench.py $(BENCH_BUS_ARGS)
