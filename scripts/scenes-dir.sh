# Sourced by the measurement scripts: sets $scenes to the shared scenes folder, as
# util/paths.h finds it: $KDGRID_SCENES, else ../shared/scenes beside the checkout or beside a
# parent folder (worktrees), else ../shared/scenes (reported missing by the caller).
# Needs $root, the checkout.
scenes="${KDGRID_SCENES:-}"
if [[ -z "$scenes" ]]; then
  for base in "$root" "$root/.." "$root/../.."; do
    if [[ -d "$base/../shared/scenes" ]]; then
      scenes=$(cd "$base/../shared/scenes" && pwd)
      break
    fi
  done
fi
scenes="${scenes:-$root/../shared/scenes}"
