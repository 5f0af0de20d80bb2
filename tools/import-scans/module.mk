# import-scans: a folder of KITTI .bin / PCD scans + poses -> LIDAR_SCAN + GROUND_TRUTH log (+ map).
$(eval $(call cxx_program,import-scans,tools/import-scans))
