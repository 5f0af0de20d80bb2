# bench-terrain: ground models vs the simulator's true height field, and simdrive's
# cost of a 60 s drive with terrain (hills) vs without (default).
BENCH_TARGETS += bench-terrain
.PHONY: bench-terrain
bench-terrain: $(BIN)/simdrive maps
	@$(VPY) tools/bench-terrain/bench.py
