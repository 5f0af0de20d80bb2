# map-tiles: a site's map.pcd -> map.tiles (prepared cells in square tiles, paged by the localizer).
# It shares the localizer's map_source (the preparation the localizer also does for a
# site without map.tiles).
$(eval $(call cxx_program,map-tiles,tools/map-tiles modules/localizer/core,-lz))
$(BIN)/map-tiles: $(OBJ)/modules/localizer/map_source.o
$(OBJ)/tools/map-tiles/%.o: CPPFLAGS += -I$(TOP)/modules/localizer/core -I$(TOP)/modules/localizer
