#!/usr/bin/env bash
# Prepare everything tests/vcan/vcanrun.py needs to give a command a SocketCAN vcan0:
#   - host packages: qemu-system-x86, busybox-static, can-utils, iproute2, kmod, cpio
#   - a Debian kernel (vmlinuz + the CAN, virtio and 9p modules) and a tiny initramfs,
#     cached under ${FTCAP_VCAN_CACHE:-${XDG_CACHE_HOME:-~/.cache}/ftcap-hil/vcan-vm}/<kernel>/
# Idempotent: each step is skipped when its result is already there.
# Run as root (apt); with sudo the cache goes to the invoking user's home.
# Environment: FTCAP_VCAN_KERNEL_PKG (e.g. linux-image-6.1.0-56-amd64) pins the kernel.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
stage1="$here/guest-stage1.sh"

say() { printf 'vcan-setup: %s\n' "$*"; }
die() { printf 'vcan-setup: ERROR: %s\n' "$*" >&2; exit 1; }

# --- where the cache lives (the invoking user's, also under sudo) ---------------------------
owner=""
if [[ -n "${SUDO_USER:-}" && "${SUDO_USER}" != root ]]; then
    owner="$SUDO_USER"
    user_home="$(getent passwd "$SUDO_USER" | cut -d: -f6)"
    default_cache="$user_home/.cache/ftcap-hil/vcan-vm"
else
    default_cache="${XDG_CACHE_HOME:-$HOME/.cache}/ftcap-hil/vcan-vm"
fi
cache="${FTCAP_VCAN_CACHE:-$default_cache}"

# --- host packages ---------------------------------------------------------------------------
packages=(qemu-system-x86 busybox-static can-utils iproute2 kmod cpio xz-utils zstd)
missing=()
for p in "${packages[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed' || missing+=("$p")
done
apt_updated=0
apt_update() {
    if [[ $apt_updated == 0 ]]; then
        say "apt-get update"
        apt-get update -qq || die "apt-get update failed"
        apt_updated=1
    fi
}
if ((${#missing[@]})); then
    [[ $EUID == 0 ]] || die "missing packages: ${missing[*]}; run: sudo bash $0"
    apt_update
    say "apt-get install ${missing[*]}"
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
        "${missing[@]}" >/dev/null || die "apt-get install ${missing[*]} failed"
else
    say "host packages present: ${packages[*]}"
fi
[[ -x /bin/busybox ]] || die "/bin/busybox missing (package busybox-static)"

# --- which kernel ----------------------------------------------------------------------------
kernel_pkg="${FTCAP_VCAN_KERNEL_PKG:-}"
find_kernel_pkg() {
    apt-cache depends linux-image-amd64 2>/dev/null \
        | awk '/Depends: linux-image-[0-9]/ {print $2; exit}'
}
if [[ -z "$kernel_pkg" ]]; then
    kernel_pkg="$(find_kernel_pkg)"
    if [[ -z "$kernel_pkg" ]]; then
        [[ $EUID == 0 ]] || die "apt-cache knows no linux-image-amd64; run: sudo bash $0"
        apt_update
        kernel_pkg="$(find_kernel_pkg)"
    fi
fi
[[ "$kernel_pkg" =~ ^linux-image-(.+)$ ]] || die "cannot find the kernel package (got '$kernel_pkg')"
kver="${BASH_REMATCH[1]}"
dest="$cache/$kver"
say "kernel $kver -> $dest"
if [[ -n "$owner" ]]; then sudo -u "$owner" mkdir -p "$dest" 2>/dev/null || true; fi
mkdir -p "$dest"

# --- kernel and modules ----------------------------------------------------------------------
# Modules the guest loads, in the order modprobe resolves them (dependencies first).
wanted_modules=(virtio_pci 9pnet_virtio 9p can can_raw can_bcm vcan)
work="$(mktemp -d "${TMPDIR:-/tmp}/vcan-setup.XXXXXX")"
trap 'rm -rf "$work"' EXIT

if [[ -s "$dest/vmlinuz" && -s "$dest/modules.tar" \
    && "$(cat "$dest/modules.wanted" 2>/dev/null)" == "${wanted_modules[*]}" ]]; then
    say "kernel cached"
else
    say "apt-get download $kernel_pkg"
    (cd "$work" && apt-get download -q -o APT::Sandbox::User=root "$kernel_pkg" >/dev/null) \
        || die "apt-get download $kernel_pkg failed"
    say "unpacking $(basename "$work"/*.deb)"
    dpkg-deb -x "$work"/*.deb "$work/root"
    moddir="$work/root/lib/modules/$kver"
    [[ -d "$moddir" ]] || die "no $moddir in $kernel_pkg"
    depmod -b "$work/root" "$kver" || die "depmod failed"
    mkdir -p "$work/mods"
    : >"$work/mods/order"
    for m in "${wanted_modules[@]}"; do
        modprobe -d "$work/root" -S "$kver" --show-depends "$m" \
            || die "module $m not found in $kernel_pkg"
    done | awk '$1 == "insmod" && !seen[$2]++ {print $2}' | while read -r ko; do
        name="$(basename "$ko")"
        case "$name" in  # busybox insmod wants plain ELF objects
            *.ko.xz) xz -dc "$ko" >"$work/mods/${name%.xz}"; name="${name%.xz}" ;;
            *.ko.zst) zstd -qdc "$ko" >"$work/mods/${name%.zst}"; name="${name%.zst}" ;;
            *.ko.gz) gzip -dc "$ko" >"$work/mods/${name%.gz}"; name="${name%.gz}" ;;
            *.ko) cp "$ko" "$work/mods/$name" ;;
            *) die "unexpected module file $ko" ;;
        esac
        echo "$name" >>"$work/mods/order"
    done
    say "modules: $(tr '\n' ' ' <"$work/mods/order")"
    tar -C "$work/mods" -cf "$dest/modules.tar.new" .
    cp "$work/root/boot/vmlinuz-$kver" "$dest/vmlinuz.new"
    mv "$dest/modules.tar.new" "$dest/modules.tar"
    echo "${wanted_modules[*]}" >"$dest/modules.wanted"
    mv "$dest/vmlinuz.new" "$dest/vmlinuz"
fi

extract_vmlinux() {  # bzImage -> ELF, for xz-compressed kernels (Debian's)
    local off
    off="$(LC_ALL=C grep -m1 -aboP '\xfd7zXZ\x00' "$1" | cut -d: -f1)" || return 1
    [[ -n "$off" ]] || return 1
    xz -dc --single-stream < <(tail -c +"$((off + 1))" "$1") >"$2" 2>/dev/null || return 1
    [[ "$(od -An -tx1 -N4 "$2" | tr -d ' ')" == 7f454c46 ]]
}

# An uncompressed ELF vmlinux boots through its PVH entry and saves the ~3 s that TCG spends
# unpacking the bzImage on every run. Optional: vcanrun.py falls back to vmlinuz.
if [[ -s "$dest/vmlinux" ]]; then
    say "vmlinux cached"
else
    say "extracting vmlinux from vmlinuz"
    if extract_vmlinux "$dest/vmlinuz" "$work/vmlinux"; then
        mv "$work/vmlinux" "$dest/vmlinux"
    else
        say "could not extract an xz-compressed ELF vmlinux; the VM will boot vmlinuz (slower)"
    fi
fi

# --- initramfs -------------------------------------------------------------------------------
# Rebuilt when stage 1, busybox or the modules change (the stamp is their hash).
stamp="$(cat "$stage1" /bin/busybox "$dest/modules.tar" | sha256sum | cut -c1-16)"
if [[ -s "$dest/initrd.img" && "$(cat "$dest/initrd.stamp" 2>/dev/null)" == "$stamp" ]]; then
    say "initramfs cached"
else
    say "building initramfs"
    ir="$work/initramfs"
    mkdir -p "$ir"/{bin,dev,proc,sys,job,newroot,lib/modules}
    cp /bin/busybox "$ir/bin/busybox"
    tar -C "$ir/lib/modules" -xf "$dest/modules.tar"
    install -m 0755 "$stage1" "$ir/init"
    # The kernel opens /dev/console before init runs; stage 1 also reopens it after devtmpfs.
    if [[ $EUID == 0 ]]; then mknod -m 600 "$ir/dev/console" c 5 1; fi
    (cd "$ir" && find . -print0 | cpio --null -o -H newc --quiet | gzip -1) >"$dest/initrd.img.new"
    mv "$dest/initrd.img.new" "$dest/initrd.img"
    echo "$stamp" >"$dest/initrd.stamp"
fi

echo "$kver" >"$cache/current"
for old in "$cache"/*/; do  # images of kernels Debian has since replaced
    if [[ "$(basename "$old")" != "$kver" ]]; then
        say "removing the old image $old"
        rm -rf "$old"
    fi
done
if [[ -n "$owner" ]]; then chown -R "$owner:" "$cache"; fi
say "ready: $(du -sh "$dest" | cut -f1) in $dest (current kernel recorded in $cache/current)"
