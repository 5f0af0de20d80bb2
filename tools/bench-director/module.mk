# bench-director: cost per POSE update (C, director core) and arrival timing (simdrive + director).
$(eval $(call c_program,bench-director,tools/bench-director modules/director/core,-lccd))

BENCH_TARGETS += bench-director
.PHONY: bench-director
bench-director: $(BIN)/bench-director $(BIN)/director $(BIN)/simdrive
	@$(BIN)/bench-director
	@echo
	@$(VPY) tools/bench-director/timing.py --seeds 1,2,3,4,5
