#!/bin/bash
# node (fast, the demo's exact panel, rerun connect to the served viewer) + staircase operator; SIGINT the node
# after. $1: the viewer's gRPC proxy URL (docs/tools/rerun_screenshot.py --live passes it as {grpc}).
cd "$(dirname "$0")/../.."
# a domain no DDS participant on this host uses (the one-command programs' own choice; a small race with a program
# started at the same instant)
DOMAIN=$(.venv/bin/python -c 'from panel_rig.domains import private_domain_id; print(private_domain_id())')
export ROS_DOMAIN_ID=$DOMAIN ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST ROS_LOG_DIR=out/ros_log_live
GRPC="$1"
.venv/bin/rig_node --fast --params config/tang_dowell_2002.yaml --ros-args -r __ns:=/rig \
  --params-file config/rig.yaml -p "rerun:=connect:$GRPC" -p fast:=true -p fast_max_realtime_factor:=20.0 \
  -p model.variant:=exact -p fast_wait_for_command:=true &
NODE=$!
.venv/bin/rig_operator --profile config/staircase.yaml --namespace /rig --timeout 30 --startup-timeout 180
kill -INT $NODE; wait $NODE
