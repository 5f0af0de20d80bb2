# bench-terrain: ground models vs the simulator's true height field, and simdrive's
# cost of a 60 s drive with terrain (hills) vs without (default).
BENCH_TARGETS += bench-terrain
.PHONY: bench-terrain
bench-terrain: $(BIN)/simdrive maps
	@$(VPY) tools/bench-terrain/bench.py

# The localizer on the hills and on the default site's messier world (simdrive --with
# lead,crossing,pedestrians,roof), 3 profiles x seeds 1-3: build/bench/terrain-localizer.json.
BENCH_TARGETS += bench-terrain-localizer
.PHONY: bench-terrain-localizer
bench-terrain-localizer: $(BIN)/simdrive $(BIN)/localizer $(BIN)/can $(BIN)/log-merge maps
	@$(VPY) tools/bench-terrain/bench.py --localizer --skip-ground --loc-seeds 1,2,3 \
		--loc-sites hills,default:lead+crossing+pedestrians+roof --work $(BUILD)/bench-terrain-loc

# Lab twin vs road with the localizer's POSE on the hills and the default site: build/bench/terrain-twin.json.
BENCH_TARGETS += bench-terrain-twin
.PHONY: bench-terrain-twin
bench-terrain-twin: $(BIN)/simdrive $(BIN)/localizer $(BIN)/can $(BIN)/log-merge $(BIN)/lab_vehicle $(BIN)/director maps
	@$(VPY) tools/bench-terrain/bench.py --twin --skip-ground --sites hills,default --work $(BUILD)/bench-terrain-twin
