# localizer: LiDAR localization in the prior map (core: filter, pipeline, registration).
$(eval $(call cxx_program,localizer,modules/localizer modules/localizer/core,-lz))

# Module-level figures on simulated drives (long: simulates ~8 min of driving; cached).
BENCH_TARGETS += bench-localizer-drive
.PHONY: bench-localizer-drive
bench-localizer-drive: $(BIN)/localizer $(BIN)/simdrive $(BIN)/can $(BIN)/log-merge
	@$(VPY) modules/localizer/bench/bench_drive.py

# Resident memory of the localizer as it runs (map paged in tiles) vs every tile held (the
# whole map), over a one-hour replay (a 232 s lap looped 16 times; replayed faster than
# real time, 20-40 minutes on the shared machine). LOCMEM_LOOPS=N for fewer laps.
BENCH_TARGETS += bench-localizer-memory
.PHONY: bench-localizer-memory
LOCMEM_LOOPS ?= 16
bench-localizer-memory: $(BIN)/localizer $(BIN)/simdrive $(BIN)/can $(BIN)/log-merge maps/default/map.tiles
	@$(VPY) modules/localizer/bench/bench_memory.py --loops $(LOCMEM_LOOPS)

# Unit tests of the filter (run by tests/test_c_units.py).
$(eval $(call cxx_test,test_localizer_filter,modules/localizer/core/filter.cpp tests/c/test_localizer_filter.cpp))
