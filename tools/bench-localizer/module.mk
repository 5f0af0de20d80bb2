# bench-localizer: the localizer's scan-to-map registration vs PCL NDT and small_gicp.
$(eval $(call cxx_program,bench-localizer,tools/bench-localizer modules/localizer/core,$(shell pkg-config --libs pcl_registration pcl_kdtree pcl_search 2>/dev/null)))
$(OBJ)/tools/bench-localizer/%.o: CPPFLAGS += -I$(TOP)/modules/localizer/core

.PHONY: bench-localizer bench-localizer-real
BENCH_TARGETS += bench-localizer

# A 60 s drive on the default site (drive day: other parked cars, traffic), every 2nd
# scan (~300) for ours, every 15th of those (~20) for the baselines as well.
LOCREG_BENCH := $(BUILD)/bench/localizer
$(LOCREG_BENCH)/drive.lcm: $(BIN)/simdrive $(DEFAULT_SITE)/map.pcd vehicles/prius2017.yaml
	@echo "  SIM     $(@D) (60 s, seed 11)"
	@rm -rf $(@D).tmp && $(BIN)/simdrive --seed 11 --duration 60 --speed-profile normal --quiet \
	    --site $(DEFAULT_SITE) --vehicle vehicles/prius2017.yaml --out $(@D).tmp && \
	  mkdir -p $(@D) && mv $(@D).tmp/drive.lcm $@ && rm -rf $(@D).tmp

bench-localizer: $(BIN)/bench-localizer $(LOCREG_BENCH)/drive.lcm $(DEPS)
	@$(BIN)/bench-localizer --log $(LOCREG_BENCH)/drive.lcm --map $(DEFAULT_SITE)/map.pcd \
	    --vehicle vehicles/prius2017.yaml --every 2 --baseline-every 15 \
	    --dump $(LOCREG_BENCH)/baseline.bin --json $(LOCREG_BENCH)/results.json
	@$(VPY) tools/bench-localizer/bench.py $(LOCREG_BENCH)/baseline.bin $(LOCREG_BENCH)/results.json

# Unit tests of the registration core (run by make test through tests/test_c_units.py).
LOCREG_CORE := modules/localizer/core/registration.cpp modules/localizer/core/regmap.cpp modules/localizer/core/deskew.cpp
$(eval $(call cxx_test,test_registration,tests/c/test_registration.cpp $(LOCREG_CORE)))
$(OBJ)/tests/c/test_registration.o: CPPFLAGS += -I$(TOP)/modules/localizer/core

# Real LiDAR (optional; reads ../shared/data, never copied into the project): MulRan
# Riverside02 keyframes. Map from the even scans (import-scans --every 2), odd scans
# localized from starts perturbed uniformly within 2 m / 10 deg yaw (global align,
# seeded), and from tracking and 1 m / 3 deg starts; errors are distances to the
# dataset's own SLAM poses (an estimate, not ground truth).
MULRAN := $(abspath $(TOP)/../shared/data/lidar_seq_mulran_riverside02_part1)
LOCREG_REAL := $(BUILD)/bench/localizer-real
bench-localizer-real: $(BIN)/bench-localizer $(BIN)/import-scans
	@if [ ! -d "$(MULRAN)" ]; then echo "bench-localizer-real: skipped, $(MULRAN) is absent"; exit 0; fi; \
	mkdir -p $(LOCREG_REAL) && \
	$(BIN)/import-scans --scans $(MULRAN)/Scans --poses $(MULRAN)/optimized_poses.txt --times $(MULRAN)/times.txt \
	    --every 2 --map-out $(LOCREG_REAL)/map.pcd --voxel 0.15 --out $(LOCREG_REAL)/even.lcm --quiet && \
	$(BIN)/import-scans --scans $(MULRAN)/Scans --poses $(MULRAN)/optimized_poses.txt --times $(MULRAN)/times.txt \
	    --out $(LOCREG_REAL)/all.lcm --quiet && \
	$(BIN)/bench-localizer --log $(LOCREG_REAL)/all.lcm --map $(LOCREG_REAL)/map.pcd --odd --global 2,10 \
	    --baseline-every 0 --seed 1 && \
	$(BIN)/bench-localizer --log $(LOCREG_REAL)/all.lcm --map $(LOCREG_REAL)/map.pcd --odd --baseline-every 3 \
	    --dump $(LOCREG_REAL)/baseline.bin --json $(LOCREG_REAL)/results.json --seed 1 && \
	$(VPY) tools/bench-localizer/bench.py $(LOCREG_REAL)/baseline.bin $(LOCREG_REAL)/results.json
