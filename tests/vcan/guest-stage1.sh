#!/bin/busybox sh
# Stage 1 of the vcan VM: the initramfs' /init, baked in by setup.sh.
# Loads the virtio, 9p and CAN modules, mounts the per-run job share and hands over to the
# job's stage 2 (a copy of tests/vcan/guest-stage2.sh), so the guest logic can change
# without rebuilding the initramfs.
/bin/busybox --install -s /bin
export PATH=/bin
mount -t devtmpfs devtmpfs /dev
exec </dev/null >/dev/console 2>&1
mount -t proc proc /proc
mount -t sysfs sysfs /sys

fail() {
    echo "vcan-vm: stage 1: $*"
    poweroff -f
    sleep 10
}

echo "vcan-vm: stage 1: loading modules"
while read -r mod; do
    insmod "/lib/modules/$mod" || fail "insmod $mod failed"
done </lib/modules/order
mount -t 9p -o trans=virtio,version=9p2000.L,msize=262144,cache=none job /job \
    || fail "cannot mount the job share"
[ -f /job/guest-stage2.sh ] || fail "no guest-stage2.sh in the job share"
exec sh /job/guest-stage2.sh
