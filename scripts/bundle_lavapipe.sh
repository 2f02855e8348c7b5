#!/usr/bin/env bash
# Bundle this machine's lavapipe (Mesa's CPU Vulkan driver) and the libraries it needs into
# .lvp/ (git-ignored), so a machine without it (the NVIDIA hosts: no registry, no lavapipe) can
# run the lavapipe jobs on a few of its otherwise idle CPU cores.
#
# Why: the lavapipe study wants a steady machine; a shared VM's speed can drift by 2-4x within
# an hour, while the NVIDIA hosts are held whole. There, after `source .gl/env.sh`:
#     source .lvp/env.sh        # unpacks to /tmp/lvp and points the loader at lavapipe only
# glibc is taken from the host; everything else lavapipe links is bundled, except two large
# libraries that lavapipe never calls into, replaced by small stubs so the bundle fits the device
# tool's 64 MiB: Z3 (LLVM's static-analyzer solver: each function LLVM imports aborts if called)
# and ICU's data (libxml2's encoding tables; an empty table).
set -euo pipefail
cd "$(dirname "$0")/.."
lvp=/usr/lib/x86_64-linux-gnu/libvulkan_lvp.so
[ -f "$lvp" ] || { echo "no lavapipe here ($lvp); apt-get install mesa-vulkan-drivers" >&2; exit 1; }
stage=$(mktemp -d)
trap 'rm -rf "$stage"' EXIT
mkdir -p "$stage/lib" "$stage/compat"
cp -L "$lvp" "$stage/lib/"
ldd "$lvp" | awk '/=> \//{print $3}' | while read -r lib; do
  case "$(basename "$lib")" in
    libc.so.*|libm.so.*|libpthread.so.*|libdl.so.*|librt.so.*|ld-linux*) ;;
    libstdc++.so.*|libgcc_s.so.*) cp -L "$lib" "$stage/compat/" ;;
    *) cp -L "$lib" "$stage/lib/" ;;
  esac
done
stub() {  # stub SONAME C-SOURCE: a shared library of that name built from the source
  printf '%s\n' "$2" > "$stage/stub.c"
  gcc -shared -fPIC -O1 -Wl,-soname,"$1" -o "$stage/lib/$1" "$stage/stub.c"
}
z3=$(objdump -T "$stage/lib/libLLVM-15.so.1" | awk '/\*UND\*/ && $NF ~ /^Z3_/ {printf "void %s(void){abort();}\n", $NF}')
stub libz3.so.4 "#include <stdlib.h>
$z3"
stub libicudata.so.72 "const char icudt72_dat[64] = {0};"
rm -f "$stage/stub.c"
mkdir -p .lvp
tar -C "$stage" -cf - lib compat | xz -9 -T0 > .lvp/lvp.tar.xz
cat > .lvp/env.sh <<'ENV'
# Source after .gl/env.sh on a machine without lavapipe: unpack the bundle, use lavapipe only.
mkdir -p /tmp/lvp && tar -C /tmp/lvp -xJf .lvp/lvp.tar.xz
cat > /tmp/lvp/lvp_icd.json <<JSON
{"file_format_version": "1.0.0", "ICD": {"library_path": "/tmp/lvp/lib/libvulkan_lvp.so", "api_version": "1.1.230"}}
JSON
# the host's libstdc++ if it is new enough for Debian 12's LLVM, else the bundled one
if grep -qa GLIBCXX_3.4.30 "$(ldconfig -p | awk '/libstdc\+\+\.so\.6 .*x86-64/{print $NF; exit}')" 2>/dev/null; then
  export LD_LIBRARY_PATH=/tmp/lvp/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}
else
  export LD_LIBRARY_PATH=/tmp/lvp/lib:/tmp/lvp/compat${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}
fi
export VK_DRIVER_FILES=/tmp/lvp/lvp_icd.json
unset VK_ICD_FILENAMES
ENV
du -h .lvp/lvp.tar.xz
