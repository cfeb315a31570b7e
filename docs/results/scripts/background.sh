# Sourced by the long-run scripts (paper_budget.sh, ship_transam.sh, env_grid.sh). setsid
# makes such a script a session of its own, which Linux schedules as its own group
# (autogroup), across which nice does nothing: lower the group's priority as well
# (GROUP_NICE, default 10). Started from a shell instead, it leaves that shell's group alone.
read -r -a _stat < /proc/self/stat
if [[ "${_stat[5]}" == "$$" && -w /proc/self/autogroup ]]; then
  echo "${GROUP_NICE:-10}" > /proc/self/autogroup 2>/dev/null || true
fi
