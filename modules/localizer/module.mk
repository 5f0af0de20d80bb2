# localizer: LiDAR localization in the prior map (core: filter, pipeline, registration).
$(eval $(call cxx_program,localizer,modules/localizer modules/localizer/core,-lz))
# The core at -O3 (the mapper's and the tools' copies too): 9-12 % less CPU per start-up
# align on the HDL-32E pair (bench-localizer-real, 3 m / 15 deg), replays byte-identical
# (no fast-math; x86-64 without -march has no FMA to contract into).
$(OBJ)/modules/localizer/core/%.o: CXXFLAGS += -O3

# Module-level figures on simulated drives (long: simulates ~8 min of driving; cached).
BENCH_TARGETS += bench-localizer-drive
.PHONY: bench-localizer-drive
bench-localizer-drive: $(BIN)/localizer $(BIN)/simdrive $(BIN)/can $(BIN)/log-merge
	@$(VPY) modules/localizer/bench/bench_drive.py

# A street of trees (the default site without buildings; solid and porous canopies): the
# case where real data is hard and the default site is not; and a bare street (without its
# trees too: poles and parked cars that changed). Tracking over a 40 s drive and the starts
# of bench-localizer-drive; about 6 minutes. build/bench/localizer-trees.json.
BENCH_TARGETS += bench-localizer-trees
.PHONY: bench-localizer-trees
bench-localizer-trees: $(BIN)/localizer $(BIN)/simdrive $(BIN)/build-map $(BIN)/build-ground $(BIN)/map-tiles
	@$(VPY) modules/localizer/bench/tree_street.py

# Raw sweeps without point times (a dataset's x y z i .bin): a 60 s simulated drive exported,
# imported with its point times, with none and with times from azimuth (import-scans --spin),
# localized LiDAR alone; about 2 minutes. build/bench/localizer-untimed.json.
BENCH_TARGETS += bench-localizer-untimed
.PHONY: bench-localizer-untimed
bench-localizer-untimed: $(BIN)/localizer $(BIN)/simdrive $(BIN)/scan-export $(BIN)/import-scans
	@$(VPY) modules/localizer/bench/bench_untimed.py

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

# bench-localizer: the localizer's scan-to-map registration vs PCL NDT and small_gicp
# (bench/bench_main.cpp; bench/bench_gicp.py runs the small_gicp half).
$(eval $(call cxx_program,bench-localizer,modules/localizer/bench modules/localizer/core,$(shell pkg-config --libs pcl_registration pcl_kdtree pcl_search 2>/dev/null)))
$(OBJ)/modules/localizer/bench/%.o: CPPFLAGS += -I$(TOP)/modules/localizer/core

.PHONY: bench-localizer bench-localizer-real
BENCH_TARGETS += bench-localizer

# A 60 s drive on the default site (drive day: other parked cars, traffic), every 2nd
# scan (~300) for ours, every 15th of those (~20) for the baselines as well.
LOCREG_BENCH := $(BUILD)/bench/localizer
$(LOCREG_BENCH)/drive.lcm: $(BIN)/simdrive maps/default/map.pcd vehicles/prius2017.yaml
	@echo "  SIM     $(@D) (60 s, seed 11)"
	@rm -rf $(@D).tmp && $(BIN)/simdrive --seed 11 --duration 60 --speed-profile normal --quiet \
	    --site maps/default --vehicle vehicles/prius2017.yaml --out $(@D).tmp && \
	  mkdir -p $(@D) && mv $(@D).tmp/drive.lcm $@ && rm -rf $(@D).tmp

bench-localizer: $(BIN)/bench-localizer $(LOCREG_BENCH)/drive.lcm $(DEPS)
	@$(BIN)/bench-localizer --log $(LOCREG_BENCH)/drive.lcm --map maps/default/map.pcd \
	    --vehicle vehicles/prius2017.yaml --every 2 --baseline-every 15 \
	    --dump $(LOCREG_BENCH)/baseline.bin --json $(LOCREG_BENCH)/results.json
	@$(VPY) modules/localizer/bench/bench_gicp.py $(LOCREG_BENCH)/baseline.bin $(LOCREG_BENCH)/results.json

# Unit tests of the registration core (run by make test through tests/test_c_units.py).
LOCREG_CORE := modules/localizer/core/registration.cpp modules/localizer/core/regmap.cpp modules/localizer/core/deskew.cpp \
               modules/localizer/core/map_tiles.cpp modules/localizer/core/refine.cpp \
               modules/localizer/core/places.cpp modules/localizer/core/window_search.cpp
$(eval $(call cxx_test,test_registration,tests/c/test_registration.cpp $(LOCREG_CORE)))
$(OBJ)/tests/c/test_registration.o: CPPFLAGS += -I$(TOP)/modules/localizer/core

# Real LiDAR (optional; reads ../shared/data, never copied into the project).
# 1. MulRan Riverside02 keyframes: the dataset's SLAM poses are refined first
#    (reference.py: a pose graph over pairwise small_gicp GICP registrations, so the
#    reference does not come from the registration under test), the map is built
#    from the even scans at the refined poses, and every 2nd odd scan is localized
#    against the refined reference: from tracking starts (5 cm) and from
#    LOCREAL_STARTS starts per scan drawn uniformly within 3 m / 15 deg (ours: the
#    relocalisation search pb_reg_align_global around the start; baselines: aligned
#    from the start). Baselines (PCL NDT at 1 and 2 m, small_gicp GICP and VGICP) on
#    every LOCREAL_BASE_EVERY-th of those scans, same reduced points and starts.
#    The whole localizer's starts (real_starts.py) run on two splits: the odd keyframes in
#    the site of the even ones (starts-odd.json), and the even ones in the site of the odd
#    ones (starts-even.json): one sequence, two trials, so a rule tuned to one split shows;
#    starts-odd.png / starts-even.png draw where on the route they succeed and fail.
# 2. The HDL-32E pair (tests/data, BSD-3): the first scan is the map, the second is
#    localized from 100 starts within 3 m / 15 deg; reference = relative.txt.
MULRAN := $(abspath $(TOP)/../shared/data/lidar_seq_mulran_riverside02_part1)
LOCREG_REAL := $(BUILD)/bench/localizer-real
LOCREAL_STARTS ?= 20
LOCREAL_BASE_EVERY ?= 1
LOCREAL_CUTS ?= 30
LOCREAL_GUESSES ?= 90
LOCREAL_GLOBAL ?= 30
LOCREAL_BENCH = --global 3,15 --converge 0.2 --ndt-res 1,2
bench-localizer-real: $(BIN)/bench-localizer $(BIN)/import-scans $(DEPS)
	@mkdir -p $(LOCREG_REAL)/hdl32/scans && \
	echo "== HDL-32E pair (tests/data/lidar_pair_hdl32): map = first scan, second localized from 100 starts" && \
	ln -sf $(TOP)/tests/data/lidar_pair_hdl32/251370668.pcd $(TOP)/tests/data/lidar_pair_hdl32/251371071.pcd $(LOCREG_REAL)/hdl32/scans/ && \
	{ echo "1 0 0 0 0 1 0 0 0 0 1 0"; awk 'NR<=3{printf "%s %s %s %s%s", $$1, $$2, $$3, $$4, NR<3?" ":"\n"}' \
	    tests/data/lidar_pair_hdl32/relative.txt; } > $(LOCREG_REAL)/hdl32/poses.txt && \
	$(BIN)/import-scans --scans $(LOCREG_REAL)/hdl32/scans --poses $(LOCREG_REAL)/hdl32/poses.txt --every 2 \
	    --map-out $(LOCREG_REAL)/hdl32/map.pcd --voxel 0 --out $(LOCREG_REAL)/hdl32/even.lcm --quiet && \
	$(BIN)/import-scans --scans $(LOCREG_REAL)/hdl32/scans --poses $(LOCREG_REAL)/hdl32/poses.txt \
	    --out $(LOCREG_REAL)/hdl32/all.lcm --quiet && \
	$(BIN)/bench-localizer --log $(LOCREG_REAL)/hdl32/all.lcm --map $(LOCREG_REAL)/hdl32/map.pcd --odd \
	    $(LOCREAL_BENCH) --starts 100 --baseline-every 1 --timing-runs 21 --seed 1 \
	    --dump $(LOCREG_REAL)/hdl32/baseline.bin --json $(LOCREG_REAL)/hdl32-results.json && \
	$(VPY) modules/localizer/bench/bench_gicp.py $(LOCREG_REAL)/hdl32/baseline.bin $(LOCREG_REAL)/hdl32-results.json
	@if [ ! -d "$(MULRAN)" ]; then echo "bench-localizer-real: MulRan part skipped, $(MULRAN) is absent"; exit 0; fi; \
	echo "== MulRan Riverside02: reference = LiDAR odometry + pose graph over the dataset's keyframes" && \
	if [ -s $(LOCREG_REAL)/refined_poses.txt -a $(LOCREG_REAL)/refined_poses.txt -nt modules/localizer/bench/reference.py \
	     -a $(LOCREG_REAL)/refined_poses.txt -nt $(MULRAN)/optimized_poses.txt ]; then \
	  $(VPY) -c 'import json, sys; r = json.load(open(sys.argv[1])); print("reference: kept from the last run (delete %s to build it again): held-out skip-3 residual median %.3f m, p90 %.3f m" % (sys.argv[2], r["heldout_skip3_resid_m_median"], r["heldout_skip3_resid_m_p90"]))' \
	      $(LOCREG_REAL)/reference-report.json $(LOCREG_REAL)/refined_poses.txt; \
	else \
	  $(VPY) modules/localizer/bench/reference.py --scans $(MULRAN)/Scans --poses $(MULRAN)/optimized_poses.txt \
	      --times $(MULRAN)/times.txt --threads 1 \
	      --out $(LOCREG_REAL)/refined_poses.txt.tmp --report $(LOCREG_REAL)/reference-report.json && \
	  mv $(LOCREG_REAL)/refined_poses.txt.tmp $(LOCREG_REAL)/refined_poses.txt; \
	fi && \
	$(BIN)/import-scans --scans $(MULRAN)/Scans --poses $(LOCREG_REAL)/refined_poses.txt --times $(MULRAN)/times.txt \
	    --every 2 --map-out $(LOCREG_REAL)/map.pcd --voxel 0.15 --out $(LOCREG_REAL)/even.lcm --quiet && \
	$(BIN)/import-scans --scans $(MULRAN)/Scans --poses $(LOCREG_REAL)/refined_poses.txt --times $(MULRAN)/times.txt \
	    --out $(LOCREG_REAL)/all.lcm --quiet && \
	echo "== MulRan Riverside02 against the refined reference: every 2nd odd scan, $(LOCREAL_STARTS) starts each" && \
	$(BIN)/bench-localizer --log $(LOCREG_REAL)/all.lcm --map $(LOCREG_REAL)/map.pcd --odd --every 2 \
	    $(LOCREAL_BENCH) --starts $(LOCREAL_STARTS) --baseline-every $(LOCREAL_BASE_EVERY) --timing-runs 5 --seed 1 \
	    --dump $(LOCREG_REAL)/baseline.bin --json $(LOCREG_REAL)/results.json && \
	$(VPY) modules/localizer/bench/bench_gicp.py $(LOCREG_REAL)/baseline.bin $(LOCREG_REAL)/results.json \
	    --reference-report $(LOCREG_REAL)/reference-report.json && \
	echo "== MulRan Riverside02, the same scans and starts, ours with rough targets (foliage's Gaussians; off by default)" && \
	$(BIN)/bench-localizer --log $(LOCREG_REAL)/all.lcm --map $(LOCREG_REAL)/map.pcd --odd --every 2 \
	    $(LOCREAL_BENCH) --starts $(LOCREAL_STARTS) --baseline-every 0 --timing-runs 5 --seed 1 --rough-targets 1 \
	    --json $(LOCREG_REAL)/results-rough.json && \
	for split in odd even; do \
	  echo "== MulRan Riverside02, the whole localizer, LiDAR alone: the $$split scans replayed in the site of the others" && \
	  $(VPY) modules/localizer/bench/keyframe_site.py --scans $(MULRAN)/Scans --poses $(LOCREG_REAL)/refined_poses.txt \
	      --times $(MULRAN)/times.txt --vehicle vehicles/lidar_mast.yaml --out $(LOCREG_REAL)/split-$$split --log $$split && \
	  nice $(VPY) modules/localizer/bench/real_starts.py --log $(LOCREG_REAL)/split-$$split/$$split/$$split.lcm \
	      --site $(LOCREG_REAL)/split-$$split/site --vehicle vehicles/lidar_mast.yaml --cuts $(LOCREAL_CUTS) \
	      --guesses $(LOCREAL_GUESSES) --global $(LOCREAL_GLOBAL) --report $(LOCREG_REAL)/reference-report.json \
	      --times $(MULRAN)/times.txt --json $(LOCREG_REAL)/starts-$$split.json \
	      --plot $(LOCREG_REAL)/starts-$$split.png || exit 1; \
	done
