# mapper: builds a site's prior map from a recorded drive (core: LiDAR odometry on a
# rolling local map, reusing the localizer's registration core).
$(eval $(call cxx_program,mapper,modules/mapper modules/mapper/core modules/localizer/core,-lz))
$(OBJ)/modules/mapper/%.o: CPPFLAGS += -I$(TOP)/modules/localizer/core -I$(TOP)/modules/mapper/core

# ---- bench-mapper (modules/mapper/bench): ours against KISS-ICP on the same scans
