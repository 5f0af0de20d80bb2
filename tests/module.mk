# C unit tests of the common library; run by tests/test_c_units.py.
$(eval $(call c_test,test_config,tests/c/test_config.c))
$(eval $(call c_test,test_log,tests/c/test_log.c))
$(eval $(call c_test,test_bus,tests/c/test_bus.c))
$(eval $(call c_test,test_geo_math,tests/c/test_geo_math.c))
$(eval $(call c_test,test_scan,tests/c/test_scan.c))
$(eval $(call c_test,types_roundtrip,tests/c/types_roundtrip.c))
$(eval $(call c_test,test_vehicle,tests/c/test_vehicle.c))
$(eval $(call c_test,test_ground,tests/c/test_ground.c))
