# mapper: builds a site's prior map from a recorded drive (core: LiDAR odometry on a
# rolling local map, reusing the localizer's registration core).
$(eval $(call cxx_program,mapper,modules/mapper modules/mapper/core modules/localizer/core,-lz -lceres -lglog -lpng -lcjson))
$(BIN)/mapper: $(OBJ)/modules/localizer/map_source.o $(OBJ)/tools/build-ground/ground_build.o
$(OBJ)/modules/mapper/%.o: CPPFLAGS += -I$(TOP)/modules/localizer/core -I$(TOP)/modules/mapper/core \
                                       -I$(TOP)/modules/localizer -I$(TOP)/tools/build-ground

# Unit tests of the loop closure, the odometry, the GNSS anchoring and the carving (run by make test through tests/test_c_units.py).
$(eval $(call cxx_test,test_mapper_loops,tests/c/test_mapper_loops.cpp modules/mapper/core/loops.cpp modules/mapper/core/pose_graph.cpp $(LOCREG_CORE),-lceres -lglog))
$(OBJ)/tests/c/test_mapper_loops.o: CPPFLAGS += -I$(TOP)/modules/localizer/core
$(eval $(call cxx_test,test_mapper_anchor,tests/c/test_mapper_anchor.cpp modules/mapper/core/anchor.cpp modules/mapper/core/pose_graph.cpp,-lceres -lglog))
$(eval $(call cxx_test,test_mapper_odometry,tests/c/test_mapper_odometry.cpp modules/mapper/core/odometry.cpp $(LOCREG_CORE)))
$(OBJ)/tests/c/test_mapper_odometry.o: CPPFLAGS += -I$(TOP)/modules/localizer/core
$(eval $(call cxx_test,test_mapper_carve,tests/c/test_mapper_carve.cpp modules/mapper/core/carve.cpp))
$(eval $(call cxx_test,test_mapper_under,tests/c/test_mapper_under.cpp modules/mapper/core/under.cpp))
$(OBJ)/tests/c/test_mapper_carve.o: CPPFLAGS += -I$(TOP)/modules/localizer/core

# ---- bench-mapper (modules/mapper/bench): ours against KISS-ICP on the same scans
# The default site's full loop (the bench-localizer-drive cache, else simulated), the same
# loop on a street of porous trees (the site without its buildings), the hills and, when
# ../shared/data has it, MulRan Riverside02 (read, never copied): KISS-ICP (PyPI kiss-icp,
# default config, one thread) and build/bin/mapper on the sweeps of the same log (KISS-ICP
# reads them as scan-export writes them); then the localizer on three other drives with the
# default site's map and with the mapper's. Tables on stdout, build/bench/mapper.json.
#   MAPPER_SIM_LOG=FILE   the simulated loop's log instead of the cache
#   BENCH_MAPPER_ARGS=... more options of bench_mapper.py (--drives sim, --keep-scans)
BENCH_TARGETS += bench-mapper
.PHONY: bench-mapper
bench-mapper: $(BIN)/mapper $(BIN)/scan-export $(BIN)/import-scans $(BIN)/simdrive $(BIN)/localizer $(BIN)/can $(BIN)/log-merge $(DEPS)
	@$(VPY) modules/mapper/bench/bench_mapper.py $(if $(MAPPER_SIM_LOG),--sim-log $(MAPPER_SIM_LOG)) $(BENCH_MAPPER_ARGS)
