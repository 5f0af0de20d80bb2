# supervisor: keeps a stack of commands running (core/ is pure: stack files, the per-command
# state machine; main.c the shell); supervisorctl operates it over LCM.
$(eval $(call c_program,supervisor,modules/supervisor modules/supervisor/core))
$(eval $(call c_program,supervisorctl,modules/supervisor/ctl))
$(eval $(call c_test,test_supervisor,tests/c/test_supervisor.c $(call dir_c,modules/supervisor/core)))
# bench-bus: 10 minutes of the car's message load on the live bus under the supervisor
# (recorder, localizer, lab_vehicle, log-summary): nothing lost, memory flat. BENCH_BUS_ARGS=--duration 60 for a short run.
BENCH_TARGETS += bench-bus
.PHONY: bench-bus
bench-bus: $(BIN)/supervisor $(BIN)/localizer $(BIN)/lab_vehicle $(BIN)/log-summary $(BIN)/simdrive maps
	@$(VPY) modules/supervisor/bench/bench_bus.py $(BENCH_BUS_ARGS)
