# Sourced by scripts/bootstrap.sh and bench/setup_petsc.sh: install the Debian packages of a
# list that are not installed yet (apt-get as root, or through sudo), and nothing when all are.
#
#   install_missing_packages TAG PACKAGE...    # TAG prefixes the progress line
install_missing_packages() {
  local tag=$1 p
  shift
  local missing=()
  for p in "$@"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  ((${#missing[@]})) || return 0
  printf '[%s] installing Debian packages: %s\n' "$tag" "${missing[*]}"
  local sudo_cmd=()
  [ "$(id -u)" -eq 0 ] || sudo_cmd=(sudo)
  "${sudo_cmd[@]}" env DEBIAN_FRONTEND=noninteractive apt-get update -qq
  "${sudo_cmd[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
}
