# map-tiles: a site's map.pcd -> map.tiles (prepared cells in square tiles, paged by the localizer).
$(eval $(call cxx_program,map-tiles,tools/map-tiles modules/localizer/core))
$(OBJ)/tools/map-tiles/%.o: CPPFLAGS += -I$(TOP)/modules/localizer/core
