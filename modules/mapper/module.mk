# ---- bench-mapper (modules/mapper/bench): ours against KISS-ICP on the same scans
# The default site's full loop (the bench-localizer-drive cache, else simulated) and, when
# ../shared/data has it, MulRan Riverside02 (read, never copied): KISS-ICP (PyPI kiss-icp,
# default config, one thread) on the sweeps scan-export writes, and build/bin/mapper when it
# is built ("ours: not built" otherwise). Table on stdout, build/bench/mapper.json.
#   MAPPER_SIM_LOG=FILE   the simulated loop's log instead of the cache
#   BENCH_MAPPER_ARGS=... more options of bench_mapper.py (--drives sim, --keep-scans, --ours CMD)
BENCH_TARGETS += bench-mapper
.PHONY: bench-mapper
bench-mapper: $(BIN)/scan-export $(BIN)/import-scans $(BIN)/simdrive $(filter $(BIN)/mapper,$(PROGRAMS)) $(DEPS)
	@$(VPY) modules/mapper/bench/bench_mapper.py $(if $(MAPPER_SIM_LOG),--sim-log $(MAPPER_SIM_LOG)) $(BENCH_MAPPER_ARGS)
