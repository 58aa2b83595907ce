#!/usr/bin/env bash
# Debian packages the build needs, installed only when missing (idempotent):
# libclang-dev for bindgen (the v4l crate generates its V4L2 bindings at build time);
# fonts-dejavu-core for the text of the trainer's learning-curve PNGs; mesa-vulkan-drivers
# (Mesa's lavapipe, a CPU Vulkan driver, with the Vulkan loader) for the tests of the
# trainer's wgpu backend (`train --device wgpu:cpu`) on machines without a GPU; e2fsprogs,
# gdisk and fakeroot for the SD-image installer and its tests; chromium for the web page's
# browser test; GNU time for the studies' peak RSS (scripts/size-study.sh).
#
#   scripts/install-build-deps.sh          # everything the build, the tests and the studies use
#   scripts/install-build-deps.sh --demo   # the robot's build and scripts/demo.sh only:
#                                          # libclang-dev, and pip for the ImageNet weights
set -euo pipefail
need=()
dpkg -s libclang-dev >/dev/null 2>&1 || need+=(libclang-dev)
if [ "${1:-}" = --demo ]; then
  python3 -m pip --version >/dev/null 2>&1 || need+=(python3-pip)
else
  dpkg -s fonts-dejavu-core >/dev/null 2>&1 || need+=(fonts-dejavu-core)
  dpkg -s mesa-vulkan-drivers >/dev/null 2>&1 || need+=(mesa-vulkan-drivers)
  dpkg -s libvulkan1 >/dev/null 2>&1 || need+=(libvulkan1)
  # `jetpilot image install` writes with e2fsprogs (debugfs, e2fsck, e2undo) and unpacks
  # downloads with unzip/xz; its tests build SD card images with gdisk's sgdisk and mkfs.ext4
  # under fakeroot, and zip one.
  for p in e2fsprogs gdisk fakeroot unzip zip xz-utils time; do
    dpkg -s "$p" >/dev/null 2>&1 || need+=("$p")
  done
  # The web page's browser test (tests/integration/web_browser.rs) drives Debian's Chromium headless
  # through chromedriver (WebDriver).
  for p in chromium chromium-driver; do
    dpkg -s "$p" >/dev/null 2>&1 || need+=("$p")
  done
fi
if [ ${#need[@]} -gt 0 ]; then
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO=sudo
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need[@]}" >/dev/null
  echo "installed: ${need[*]}" >&2
fi
