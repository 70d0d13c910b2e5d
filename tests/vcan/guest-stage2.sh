#!/bin/busybox sh
# Stage 2 of the vcan VM, copied into each job folder by vcanrun.py and run by the
# initramfs' busybox as PID 1.
# Mounts the host root read-only at /newroot, fresh /tmp /run /dev /proc /sys, the writable
# shares listed in /job/mounts ("TAG PATH" lines) at their host paths, creates vcan0, runs
# /job/run.sh chrooted, and records its exit status in /job/rc before powering off (on a set-up failure it
# leaves /job/setup-error and no rc).
R=/newroot
OPTS=trans=virtio,version=9p2000.L,msize=262144

finish() {
    echo "vcan-vm: command exited with status $1; powering off"
    echo "$1" >/job/rc.tmp && mv /job/rc.tmp /job/rc
    sync
    poweroff -f
    sleep 10
}
fail() {  # no rc file: the host reports a set-up failure, not the command's
    echo "vcan-vm: $*" | tee -a /job/setup.log
    touch /job/setup-error
    sync
    poweroff -f
    sleep 10
}

echo "vcan-vm: stage 2: mounting the host root"
# The host never changes its root under a run, so the guest may cache it (much faster imports).
mount -t 9p -o "$OPTS,ro,cache=loose" hostroot "$R" || fail "cannot mount the host root"
mount -t tmpfs -o mode=1777 tmpfs "$R/tmp" || fail "cannot mount /tmp"
[ -d "$R/run" ] && mount -t tmpfs -o mode=755 tmpfs "$R/run"
mount -t devtmpfs devtmpfs "$R/dev" || fail "cannot mount /dev"
mkdir -p "$R/dev/pts" "$R/dev/shm"
mount -t devpts -o newinstance,ptmxmode=0666 devpts "$R/dev/pts"
mount -t tmpfs -o mode=1777 tmpfs "$R/dev/shm"
mount -t proc proc "$R/proc" || fail "cannot mount /proc"
mount -t sysfs sysfs "$R/sys" || fail "cannot mount /sys"

echo "vcan-vm: mounting the writable shares"
# Writable shares, parents first (the host sorts them). cache=mmap: writes reach the host at
# once, and programs may still mmap files there.
while read -r tag path; do
    mkdir -p "$R$path" && mount -t 9p -o "$OPTS,cache=mmap" "$tag" "$R$path" \
        || fail "cannot mount share $tag at $path"
done </job/mounts

echo "vcan-vm: creating vcan0"
chroot "$R" /bin/sh -c '
    set -e
    ip link set dev lo up
    ip link add dev vcan0 type vcan
    ip link set dev vcan0 txqueuelen 1000
    ip link set dev vcan0 up
' >>/job/setup.log 2>&1 || fail "cannot create vcan0 (see above)"

read -r jobdir </job/jobdir
echo "vcan-vm: running $jobdir/run.sh"
chroot "$R" /bin/sh "$jobdir/run.sh" </dev/null >/job/output 2>&1
finish $?
