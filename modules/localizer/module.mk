# localizer: LiDAR localization in the prior map (core: filter, pipeline, registration).
$(eval $(call cxx_program,localizer,modules/localizer modules/localizer/core))

# Module-level figures on simulated drives (long: simulates ~8 min of driving; cached).
BENCH_TARGETS += bench-localizer-drive
.PHONY: bench-localizer-drive
bench-localizer-drive: $(BIN)/localizer $(BIN)/simdrive $(BIN)/can $(BIN)/log-merge
	@$(VPY) modules/localizer/bench/bench_drive.py

# Unit tests of the filter (run by tests/test_c_units.py).
$(eval $(call cxx_test,test_localizer_filter,modules/localizer/core/filter.cpp tests/c/test_localizer_filter.cpp))
