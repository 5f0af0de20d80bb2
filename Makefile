# Portobello on LCM: top-level build.
#   make          build everything into build/ (installs missing dependencies first)
#   make test     build and run every test (pytest; ends with its summary line)
#   make demo     simulate a drive on the default site, replay it and summarise it
#   make deps     install what a fresh Debian 12 needs (idempotent)
# Each directory under common/, tools/ and modules/ may hold a module.mk fragment
# that adds its programs with the c_program / cxx_program macros below.

SHELL := /bin/bash
.DEFAULT_GOAL := all

# A fresh clone compiles about 150 files and builds the default site's map before
# `make test` or `make demo`: on every core. Not for benchmarks and fuzzing, whose
# targets must not run beside each other (they time themselves).
ifeq ($(filter bench% fuzz,$(MAKECMDGOALS)),)
MAKEFLAGS += -j$(shell nproc 2>/dev/null || echo 2)
endif

TOP     := $(CURDIR)
BUILD   := $(TOP)/build
BIN     := $(BUILD)/bin
OBJ     := $(BUILD)/obj
VENV    := $(TOP)/.venv
VPY     := $(VENV)/bin/python
DEPS    := $(VENV)/.deps-ok

# LCM: the C library, headers and lcm-gen come from the PyPI lcm 1.5.3 wheel in .venv
# (one LCM for C, Python and the tools; see docs/architecture.md for why).
LCM_DIR    := $(VENV)/lcm
LCM_CFLAGS := -I$(LCM_DIR)/include
LCM_LIBS   := -L$(LCM_DIR)/lib -Wl,-rpath,$(LCM_DIR)/lib -llcm

CC  ?= cc
CXX ?= c++
OPT ?= -O2
# Line tables only (backtraces and perf name functions and lines): full debug info (-g, for
# a debugger's variables) makes the heavy Eigen/PCL units compile 1.6 times slower
DEBUG ?= -g1
WARN     := -Wall -Wextra -Wno-unused-parameter
CPPFLAGS := -I$(TOP)/common -I$(TOP)/modules -I$(BUILD)/gen/c -I$(BUILD)/gen/cpp $(LCM_CFLAGS) -DPB_SOURCE_DIR='"$(TOP)"'
CFLAGS   := -std=gnu11 $(OPT) $(DEBUG) $(WARN) -MMD -MP
CXXFLAGS := -std=c++17 $(OPT) $(DEBUG) $(WARN) -MMD -MP
PCL_CFLAGS = $(shell pkg-config --cflags pcl_common pcl_io pcl_filters eigen3 2>/dev/null)
PCL_LIBS   = $(shell pkg-config --libs pcl_common pcl_io pcl_filters 2>/dev/null)
BASE_LIBS  := $(LCM_LIBS) -lyaml -lpthread -lm

PROGRAMS :=
TEST_PROGRAMS :=
BENCH_TARGETS :=   # a module.mk adds its bench-NAME target here; `make bench` runs them all

# ---------------------------------------------------------------- dependencies
.PHONY: deps
deps:
	@bash tools/deps.sh

# Re-run the installer when its inputs changed or anything it installs went missing.
ifneq ($(shell bash tools/deps.sh --check >/dev/null 2>&1 && echo ok),ok)
.PHONY: $(DEPS)
endif
$(DEPS): tools/deps.sh tools/requirements.txt
	@bash tools/deps.sh

# ---------------------------------------------------------------- lcm types
LCMTYPES  := $(sort $(wildcard lcmtypes/*.lcm))
TYPE_SRCS := $(patsubst lcmtypes/%.lcm,$(BUILD)/gen/c/portobello_%.c,$(LCMTYPES))
TYPE_OBJS := $(patsubst $(BUILD)/gen/c/%.c,$(OBJ)/gen/%.o,$(TYPE_SRCS))
GEN_STAMP := $(BUILD)/gen/.stamp

$(GEN_STAMP): $(LCMTYPES) | $(DEPS)
	@rm -rf $(BUILD)/gen $(BUILD)/python/portobello
	@mkdir -p $(BUILD)/gen/c $(BUILD)/gen/cpp $(BUILD)/python
	@echo "  LCMGEN  $(words $(LCMTYPES)) types"
	@$(VENV)/bin/lcm-gen -c --c-cpath $(BUILD)/gen/c --c-hpath $(BUILD)/gen/c \
	    -x --cpp-hpath $(BUILD)/gen/cpp -p --ppath $(BUILD)/python $(LCMTYPES)
	@touch $@

$(TYPE_SRCS): $(GEN_STAMP) ;

$(OBJ)/gen/%.o: $(BUILD)/gen/c/%.c
	@mkdir -p $(@D)
	@echo "  CC      $(notdir $<)"
	@$(CC) $(CPPFLAGS) $(CFLAGS) -Wno-unused -c $< -o $@

$(BUILD)/lib/libportobello_types.a: $(TYPE_OBJS)
	@mkdir -p $(@D)
	@rm -f $@ && ar rcs $@ $^

# ---------------------------------------------------------------- common library
COMMON_C    := $(sort $(wildcard common/*.c))
COMMON_CXX  := $(sort $(wildcard common/*.cpp))
COMMON_OBJS := $(patsubst %.c,$(OBJ)/%.o,$(COMMON_C))
COMMON_CXX_OBJS := $(patsubst %.cpp,$(OBJ)/%.o,$(COMMON_CXX))
LIB_COMMON  := $(BUILD)/lib/libpb_common.a
LIB_COMMON_CXX := $(BUILD)/lib/libpb_common_cxx.a
LIB_TYPES   := $(BUILD)/lib/libportobello_types.a

$(LIB_COMMON): $(COMMON_OBJS)
	@mkdir -p $(@D)
	@rm -f $@ && ar rcs $@ $^

$(LIB_COMMON_CXX): $(COMMON_CXX_OBJS)
	@mkdir -p $(@D)
	@rm -f $@ && ar rcs $@ $^

# Every object waits for the generated headers.
$(OBJ)/%.o: %.c $(GEN_STAMP)
	@mkdir -p $(@D)
	@echo "  CC      $<"
	@$(CC) $(CPPFLAGS) $(CFLAGS) -c $< -o $@

$(OBJ)/%.o: %.cpp $(GEN_STAMP)
	@mkdir -p $(@D)
	@echo "  CXX     $<"
	@$(CXX) $(CPPFLAGS) $(PCL_CFLAGS) $(CXXFLAGS) -c $< -o $@

# Sources of one or more directories.
dir_c   = $(sort $(foreach d,$(1),$(wildcard $(d)/*.c)))
dir_cxx = $(sort $(foreach d,$(1),$(wildcard $(d)/*.cpp)))

# link TARGET OBJECTS LINKER ARCHIVES [LIBS]: the link rule of every program and test:
# the objects, the archives (prerequisites too), LIBS (-l flags), then the base libraries.
define link
$(1): $(2) $(4)
	@mkdir -p $$(@D)
	@echo "  LD      $$(notdir $$@)"
	@$(3) -o $$@ $$(filter %.o,$$^) $(4) $(5) $$(BASE_LIBS)
endef

# c_program NAME DIRS [EXTRA_LIBS]: every .c in DIRS is linked into build/bin/NAME.
define c_program
PROGRAMS += $(BIN)/$(1)
$(call link,$(BIN)/$(1),$(patsubst %.c,$(OBJ)/%.o,$(call dir_c,$(2))),$$(CC) $$(CFLAGS),$(LIB_COMMON) $(LIB_TYPES),$(3))
endef

# cxx_program NAME DIRS [EXTRA_LIBS]: every .c and .cpp in DIRS, linked with PCL.
define cxx_program
PROGRAMS += $(BIN)/$(1)
$(call link,$(BIN)/$(1),$(patsubst %.c,$(OBJ)/%.o,$(call dir_c,$(2))) $(patsubst %.cpp,$(OBJ)/%.o,$(call dir_cxx,$(2))),$$(CXX) $$(CXXFLAGS),$(LIB_COMMON_CXX) $(LIB_COMMON) $(LIB_TYPES),$(3) $$(PCL_LIBS))
endef

# cxx_test NAME FILES [EXTRA_LIBS]: a C++ unit test (.c/.cpp files), linked with PCL; run
# by tests/test_c_units.py like a C one.
define cxx_test
TEST_PROGRAMS += $(BUILD)/tests/$(1)
$(call link,$(BUILD)/tests/$(1),$(patsubst %.cpp,$(OBJ)/%.o,$(patsubst %.c,$(OBJ)/%.o,$(2))),$$(CXX) $$(CXXFLAGS),$(LIB_COMMON_CXX) $(LIB_COMMON) $(LIB_TYPES),$(3) $$(PCL_LIBS))
endef

# c_test NAME FILE: a C unit test, run by tests/test_c_units.py.
define c_test
TEST_PROGRAMS += $(BUILD)/tests/$(1)
$(call link,$(BUILD)/tests/$(1),$(patsubst %.c,$(OBJ)/%.o,$(2)),$$(CC) $$(CFLAGS),$(LIB_COMMON) $(LIB_TYPES))
endef

# Sites: maps/module.mk adds build rules for generated site data (the default site's prior map).
.PHONY: maps
maps:

include $(sort $(wildcard common/module.mk tools/*/module.mk modules/*/module.mk tests/module.mk maps/module.mk))

# ---------------------------------------------------------------- top-level targets
.PHONY: all programs tests test demo clean bench fuzz test-real
all: $(LIB_TYPES) $(LIB_COMMON) $(PROGRAMS) $(TEST_PROGRAMS) maps

programs: $(PROGRAMS)

# pytest drives everything: the C unit tests, the tools, the logs.
# A passing test's scratch folder is removed (a session writes several GB of logs
# and maps); a failing test's is kept for inspection.
PYTEST = $(VPY) -m pytest -q -p no:cacheprovider -o tmp_path_retention_policy=failed
# Two phases: the offline tests (replays, simulated drives, files) on every core, one test
# module per worker (pytest-xdist), then the tests marked `live` (real time on a bus, a
# page talking to it) without the offline ones, so no CPU-bound work slows them. The live
# ones mostly wait on real time (0.4 of a core on average), so two modules of them run at
# once (each test has its own ports); their timing figures stay close to one at a time
# (kill -9 to a new STATUS 0.10-0.28 s, stale sweeps skipped 18-21). Both phases always
# run; make fails if either failed, or if neither selected a test (pytest's 5; one phase
# may select none, e.g. with PYTEST_ARGS=-k).
TEST_JOBS ?= $(shell nproc 2>/dev/null || echo 2)
LIVE_JOBS ?= $(shell [ "$$(nproc 2>/dev/null || echo 1)" -ge 2 ] && echo 2 || echo 1)
test: all
	@rc=0; none=0; \
	$(PYTEST) -n $(TEST_JOBS) --dist loadfile -m "not live" tests $(PYTEST_ARGS) || { r=$$?; [ $$r -eq 5 ] && none=$$((none+1)) || rc=$$r; }; \
	echo "make test: the live tests, two modules at a time"; \
	$(PYTEST) -n $(LIVE_JOBS) --dist loadfile -m live tests $(PYTEST_ARGS) || { r=$$?; [ $$r -eq 5 ] && none=$$((none+1)) || rc=$$r; }; \
	[ $$none -lt 2 ] || { echo "make test: no test selected" >&2; rc=5; }; \
	exit $$rc

# Optional: tests on ../shared/data that may not be copied into the project.
test-real: all
	@$(PYTEST) -m real tests $(PYTEST_ARGS)

DEMO_DIR ?= $(BUILD)/demo
# The demo needs the programs and the default site only (not the tests or maps/hills):
# from a fresh clone it must finish within 10 minutes on 2 cores.
demo: $(LIB_TYPES) $(LIB_COMMON) $(PROGRAMS) maps/default/map.pcd maps/default/ground.yaml maps/default/map.tiles
	@bash tools/demo.sh $(DEMO_DIR)

# libFuzzer + ASan/UBSan on every parser, FUZZ_RUNS executions each (default 1,000,000).
fuzz: $(GEN_STAMP)
	@bash tests/fuzz/run.sh

# Benchmarks (tables with their baselines, measured in the same run); not in make test.
bench: $(BENCH_TARGETS)

clean:
	rm -rf $(BUILD)

-include $(shell find $(OBJ) -name '*.d' 2>/dev/null)
