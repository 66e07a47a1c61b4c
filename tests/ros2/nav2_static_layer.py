#!/usr/bin/env python3
"""What Nav2's StaticLayer makes of isochron's activity grid, release by release.

A re-implementation, in Python and from the C++ source of each release (nothing of
isochron), of the two steps of nav2_costmap_2d/plugins/static_layer.cpp that decide
a cell's cost:

* `StaticLayer::interpretValue`: an OccupancyGrid value (int8, read as unsigned
  char) to a costmap cost;
* `StaticLayer::updateCosts`: the layer onto the costmap below it —
  `CostmapLayer::updateWithMax` (NO_INFORMATION in the layer is skipped) in a
  costmap that is not rolling, `max(layer, master)` in a rolling one (with
  `use_maximum: true`; overwrite without it).

The parameters are Nav2's defaults (`Costmap2DROS`, src/costmap_2d_ros.cpp), then
nav2_bringup's params/nav2_params.yaml of the same release (`track_unknown_space:
true` in the global costmap only, every release), then each costmap's keys in
the shipped snippet (config/nav2-activity-layer.yaml) — with `--set
costmap.key=value` overrides.

Input: a grid as costmap_listener.py prints it (JSON: "data", "width", ...). The
costmap below the activity layer, the robot's own layers, is made up here:
lethal obstacles (254) on a lattice of cells, the rest free (0), and in the global
costmap (tracking unknown space) a band of NO_INFORMATION (255) where the robot's
map is unknown.

Prints one JSON object: {"<release>": {"global_costmap": {...}, "local_costmap":
{...}}} with, per costmap:
  "max_cost": the highest cost a known activity cell (not -1) maps to,
  "obstacles": cells the activity alone makes INSCRIBED (253) or LETHAL (254),
  "inscribed", "lethal": the same, split,
  "wiped": lethal cells of the robot's layers that are no longer lethal after the
           activity layer,
  "unknown": known cells of the robot's layers that the activity layer makes
           NO_INFORMATION (255),
  "cells": cells compared.

Usage: nav2_static_layer.py --grid GRID.json --params config/nav2-activity-layer.yaml
       [--set local_costmap.track_unknown_space=true ...]
"""

import argparse
import json

import yaml

FREE_SPACE = 0
INSCRIBED_INFLATED_OBSTACLE = 253
LETHAL_OBSTACLE = 254
NO_INFORMATION = 255

# Each release's branch of ros-navigation/navigation2 as read (commit), and the
# lines of nav2_costmap_2d/plugins/static_layer.cpp modelled below.
RELEASES = {
    "humble": {"commit": "3c3db59d6", "interpret": 263, "inscribed": None, "rolling_max": 457},
    "jazzy": {"commit": "f4108e5b1", "interpret": 269, "inscribed": None, "rolling_max": 479},
    "kilted": {"commit": "71a1d84f4", "interpret": 265, "inscribed": None, "rolling_max": 462},
    # Since PR #5781: `value == inscribed_obstacle_cost_value_` → INSCRIBED.
    "lyrical": {"commit": "aa3dab8da", "interpret": 282, "inscribed": 289, "rolling_max": 503},
    "rolling": {"commit": "a3a97043e", "interpret": 282, "inscribed": 289, "rolling_max": 503},
}

# Costmap2DROS's declarations (src/costmap_2d_ros.cpp), the same values on every
# release; inscribed_obstacle_cost_value exists on Lyrical and Rolling only.
NAV2_DEFAULTS = {
    "lethal_cost_threshold": 100,
    "trinary_costmap": True,
    "unknown_cost_value": 255,
    "use_maximum": False,
    "track_unknown_space": False,
    "inscribed_obstacle_cost_value": 99,
    "rolling_window": False,
}

# nav2_bringup/params/nav2_params.yaml, every release.
BRINGUP = {
    "global_costmap": {"track_unknown_space": True},
    "local_costmap": {"rolling_window": True},
}


def interpret_value(value, p, release):
    """StaticLayer::interpretValue of `release` with parameters `p`."""
    value &= 0xFF  # int8 → unsigned char
    unknown = p["unknown_cost_value"] & 0xFF
    if p["track_unknown_space"] and value == unknown:
        return NO_INFORMATION
    if not p["track_unknown_space"] and value == unknown:
        return FREE_SPACE
    if RELEASES[release]["inscribed"] and value == (p["inscribed_obstacle_cost_value"] & 0xFF):
        return INSCRIBED_INFLATED_OBSTACLE
    lethal = max(min(p["lethal_cost_threshold"], 100), 0)
    if value >= lethal:
        return LETHAL_OBSTACLE
    if p["trinary_costmap"]:
        return FREE_SPACE
    # double → unsigned char: truncation.
    return int(value / lethal * LETHAL_OBSTACLE)


def update_costs(layer, master, p):
    """StaticLayer::updateCosts onto `master` (the layer covers it exactly)."""
    if not p["rolling_window"]:
        if not p["use_maximum"]:
            return list(layer)  # updateWithTrueOverwrite
        out = []
        for cost, old in zip(layer, master):  # CostmapLayer::updateWithMax
            if cost == NO_INFORMATION:
                out.append(old)
            elif old == NO_INFORMATION or old < cost:
                out.append(cost)
            else:
                out.append(old)
        return out
    if not p["use_maximum"]:
        return list(layer)  # master_grid.setCost(i, j, getCost(mx, my))
    return [max(cost, old) for cost, old in zip(layer, master)]


def robot_layers(width, height, p):
    """The costmap below the activity layer: a lattice of lethal cells, free
    elsewhere, and where unknown space is tracked a band the robot's map does not
    know."""
    cells = []
    for j in range(height):
        for i in range(width):
            if (i + 2 * j) % 7 == 0:
                cells.append(LETHAL_OBSTACLE)
            elif p["track_unknown_space"] and j < height // 6:
                cells.append(NO_INFORMATION)
            else:
                cells.append(FREE_SPACE)
    return cells


def parse_value(text):
    return yaml.safe_load(text)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid", required=True)
    parser.add_argument("--params", required=True)
    parser.add_argument("--set", action="append", default=[], metavar="COSTMAP.KEY=VALUE")
    args = parser.parse_args()

    with open(args.grid) as f:
        grid = json.load(f)
    with open(args.params) as f:
        snippet = yaml.safe_load(f)
    data = grid["data"]
    width, height = grid["width"], grid["height"]
    assert len(data) == width * height, "the grid's data does not fill it"

    result = {}
    for release in RELEASES:
        result[release] = {}
        for costmap in ["global_costmap", "local_costmap"]:
            p = dict(NAV2_DEFAULTS)
            p.update(BRINGUP[costmap])
            section = snippet[costmap][costmap]["ros__parameters"]
            p.update({k: v for k, v in section.items() if not isinstance(v, (dict, list))})
            for item in args.set:
                key, value = item.split("=", 1)
                where, name = key.split(".", 1)
                if where == costmap:
                    p[name] = parse_value(value)
            assert section["plugins"].index("activity_layer") > 0, "the activity layer is above the robot's"
            layer = [interpret_value(v, p, release) for v in data]
            master = robot_layers(width, height, p)
            merged = update_costs(layer, master, p)
            known = [c for v, c in zip(data, layer) if v != -1]
            result[release][costmap] = {
                "max_cost": max(known, default=None),
                "inscribed": sum(1 for c in layer if c == INSCRIBED_INFLATED_OBSTACLE),
                "lethal": sum(1 for c in layer if c == LETHAL_OBSTACLE),
                "obstacles": sum(1 for c in layer if c in (INSCRIBED_INFLATED_OBSTACLE, LETHAL_OBSTACLE)),
                "wiped": sum(
                    1 for old, new in zip(master, merged) if old == LETHAL_OBSTACLE and new != LETHAL_OBSTACLE
                ),
                "unknown": sum(
                    1 for old, new in zip(master, merged) if old != NO_INFORMATION and new == NO_INFORMATION
                ),
                "cells": len(data),
            }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
