# director: scenario runtime (core/ is pure: scenario loader, geometry, runtime; main.c the shell).
$(eval $(call c_program,director,modules/director modules/director/core,-lccd))
# Unit test of the core (C, linked through cxx_test for its extra-libs argument).
$(eval $(call cxx_test,test_director,tests/c/test_director.c $(call dir_c,modules/director/core),-lccd))
# bench-director: cost per POSE update (C, director core) and arrival timing (simdrive + director).
$(eval $(call c_program,bench-director,modules/director/bench modules/director/core,-lccd))

BENCH_TARGETS += bench-director
.PHONY: bench-director
bench-director: $(BIN)/bench-director $(BIN)/director $(BIN)/simdrive maps
	@mkdir -p $(BUILD)/bench
	@$(BIN)/bench-director
	@echo
	@$(VPY) modules/director/bench/timing.py --seeds 1,2,3,4,5
	@echo
	@echo "Arrival timing with a human driver (simdrive --driver-spread 0.2: cruise, braking point, decel +-20 % per stop)"
	@$(VPY) modules/director/bench/timing.py --seeds 1,2,3,4,5 --driver-spread 0.2 --json $(BUILD)/bench/director-timing-varied.json
	@echo
	@echo "Arrival timing behind a lead car (simdrive --with lead) with the human driver (--driver-spread 0.2)"
	@$(VPY) modules/director/bench/timing.py --seeds 1,2,3,4,5 --driver-spread 0.2 --with lead --json $(BUILD)/bench/director-timing-lead.json
