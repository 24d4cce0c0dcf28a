# Two commands do all the set-up on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test test-fast test-ros bench install clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	# torch first, pinned: the CPU build of 2.13.0 is what these machines provide
	$(PY) -m pip install --quiet torch==2.13.0
	$(PY) -m pip install --quiet -e '.[dev,sysid]'
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	MUJOCO_GL=egl $(VENV)/bin/tacgnn demo

test: $(STAMP)
	MUJOCO_GL=egl $(PY) -m pytest

# The quick subset while working (under 2 minutes on 2 cores): no training, resuming, rendering or Warp
test-fast: $(STAMP)
	MUJOCO_GL=egl $(PY) -m pytest -m "not slow"

# The real-hand path through a real ROS 1 master (tests/test_real_ros.py): installs Debian's
# ROS 1 where apt-get runs as root, and links its Python modules into the venv (appended
# after the venv's own packages). Without ROS the tests skip and name it.
ROS_PY := /usr/lib/python3/dist-packages
ROS_MODULES := catkin catkin_pkg genmsg genpy geometry_msgs roscpp rosgraph rosgraph_msgs roslib rospkg rospy \
	sensor_msgs std_msgs
test-ros: $(STAMP)
	@if ! command -v roscore >/dev/null || [ ! -d $(ROS_PY)/rospy ]; then \
	  if command -v apt-get >/dev/null && [ "$$(id -u)" = 0 ]; then \
	    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
	      ros-core python3-rospy python3-sensor-msgs >/dev/null) \
	      || echo "test-ros: apt-get could not install ROS 1; the ROS tests will skip"; \
	  else echo "test-ros: ROS 1 is not installed and apt-get as root is not available; the ROS tests will skip"; fi; \
	fi
	@if [ -d $(ROS_PY)/rospy ]; then \
	  mkdir -p $(VENV)/ros-python; \
	  for m in $(ROS_MODULES); do ln -sfn $(ROS_PY)/$$m $(VENV)/ros-python/$$m; done; \
	  echo "$(abspath $(VENV))/ros-python" > "$$($(PY) -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')/debian_ros.pth"; \
	fi
	MUJOCO_GL=egl $(PY) -m pytest tests/test_real_ros.py -rs

bench: $(STAMP)
	$(PY) bench/bench_sim.py

clean:
	rm -rf $(VENV) outputs
