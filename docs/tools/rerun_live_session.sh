#!/bin/bash
# node (fast, rerun connect to the served viewer) + staircase operator; SIGINT the node after.
cd "$(dirname "$0")/../.."
export ROS_DOMAIN_ID=$((150 + RANDOM % 50)) ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST ROS_LOG_DIR=out/ros_log_live
GRPC="$1"
.venv/bin/python -m panel_rig.ros.node --fast --params config/tang_dowell_2002.yaml --ros-args -r __ns:=/rig \
  --params-file config/rig.yaml -p "rerun:=connect:$GRPC" -p fast:=true -p fast_max_realtime_factor:=20.0 &
NODE=$!
.venv/bin/python -m panel_rig.ros.operator --profile config/staircase.yaml --namespace /rig --timeout 30
kill -INT $NODE; wait $NODE
