# mapper: builds a site's prior map from a recorded drive (core: LiDAR odometry on a
# rolling local map, reusing the localizer's registration core).
$(eval $(call cxx_program,mapper,modules/mapper modules/mapper/core modules/localizer/core,-lz))
$(OBJ)/modules/mapper/%.o: CPPFLAGS += -I$(TOP)/modules/localizer/core -I$(TOP)/modules/mapper/core

# ---- bench-mapper (modules/mapper/bench): ours against KISS-ICP on the same scans
# The default site's full loop (the bench-localizer-drive cache, else simulated) and, when
# ../shared/data has it, MulRan Riverside02 (read, never copied): KISS-ICP (PyPI kiss-icp,
# default config, one thread) and build/bin/mapper on the sweeps of the same log (KISS-ICP
# reads them as scan-export writes them). Table on stdout, build/bench/mapper.json.
#   MAPPER_SIM_LOG=FILE   the simulated loop's log instead of the cache
#   BENCH_MAPPER_ARGS=... more options of bench_mapper.py (--drives sim, --keep-scans)
BENCH_TARGETS += bench-mapper
.PHONY: bench-mapper
bench-mapper: $(BIN)/mapper $(BIN)/scan-export $(BIN)/import-scans $(BIN)/simdrive $(DEPS)
	@$(VPY) modules/mapper/bench/bench_mapper.py $(if $(MAPPER_SIM_LOG),--sim-log $(MAPPER_SIM_LOG)) $(BENCH_MAPPER_ARGS)
