# build-map: LIDAR_SCAN + pose channel of an LCM log -> voxelised prior map (PCD).
$(eval $(call cxx_program,build-map,tools/build-map))
