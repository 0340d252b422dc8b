# Shared helpers for the scripts in scripts/xr/ (sourced, not executed).

# Absolute path of the default cached root: <checkout>/.tools/xr-root (git-ignored).
xr_default_root() {
    local here
    here=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
    echo "$here/.tools/xr-root"
}

# Every mount point at or below $1, deepest first (so they can be unmounted in order).
xr_mounts_under() {
    local root=$1
    awk -v r="$root" '$2 == r || index($2, r "/") == 1 { print $2 }' /proc/self/mounts | sort -r
}

# Unmounts everything at or below $1 (lazily if a mount is still busy). Never fails.
xr_unmount_all() {
    local root=$1 m
    for m in $(xr_mounts_under "$root"); do
        umount "$m" 2>/dev/null || umount -l "$m" 2>/dev/null || true
    done
}

# Mounts proc, sys and an rbind of /dev into the root $1 (idempotent).
xr_mount_system() {
    local root=$1
    mountpoint -q "$root/proc" || mount -t proc proc "$root/proc"
    mountpoint -q "$root/sys" || mount --rbind /sys "$root/sys"
    mountpoint -q "$root/dev" || { mount --rbind /dev "$root/dev" && mount --make-rslave "$root/dev"; }
    mountpoint -q "$root/sys" && mount --make-rslave "$root/sys" 2>/dev/null || true
}
