# occlusion: which parts of each agent real objects hide from the eye (core: OctoMap map, pipeline).
$(eval $(call cxx_program,occlusion,modules/occlusion modules/occlusion/core,-loctomap -loctomath))

# occlusion-bench: ours vs stock OctoMap (insertPointCloud, castRay) on the same sweeps and queries.
$(eval $(call cxx_program,occlusion-bench,modules/occlusion/bench modules/occlusion/core,-loctomap -loctomath))
$(OBJ)/modules/occlusion/bench/%.o: CPPFLAGS += -I$(TOP)/modules/occlusion

# Cost and agreement on a 10-minute simulated drive with OCCLUSION_TRUTH (kept under
# build/bench/occlusion; simulated once). Table and JSON: build/bench/occlusion.json.
BENCH_TARGETS += bench-occlusion
.PHONY: bench-occlusion
bench-occlusion: $(BIN)/occlusion $(BIN)/occlusion-bench $(BIN)/simdrive
	@$(VPY) modules/occlusion/bench/bench_occlusion.py

# Unit test of the map: synthetic sweeps (a car alongside, a wall, a box driving away).
$(eval $(call cxx_test,test_occ_map,tests/c/test_occ_map.cpp modules/occlusion/core/occ_map.cpp,-loctomap -loctomath))
