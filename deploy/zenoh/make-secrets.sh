#!/usr/bin/env bash
# Generates the logins of the site's Zenoh router (deploy/zenoh/router.json5): one random
# password per login, never a shipped one.
#
#   bash deploy/zenoh/make-secrets.sh                       # the logins router.json5 names
#   bash deploy/zenoh/make-secrets.sh gateway-press-line-7  # add one (then give it its ACL
#                                                           # lines in router.json5)
#
# Writes deploy/zenoh/secrets/:
#   users.txt              user:password lines: the router's dictionary_file (compose secret
#                          zenoh-users, /run/secrets/zenoh-users in the router)
#   <user>.password        one per login: a gateway's zenoh.auth.password_file (compose
#                          secret zenoh-password), a client's password
# Existing logins keep their password (run it again to add one); delete a file to renew it.
# The files are mode 0600; as root, the gateways' password files are given to the container
# user 10001 (the image's), which must read them. Never commit the secrets directory.
set -euo pipefail

DIR=${SECRETS_DIR:-$(dirname "$0")/secrets}
DEFAULT_LOGINS=(viewer operator gateway-line1 gateway-line2 gateway-demo gateway-press-line-3 gateway-two-networks)
GATEWAY_UID=10001

logins=("$@")
((${#logins[@]})) || logins=("${DEFAULT_LOGINS[@]}")

umask 077
mkdir -p "$DIR"
printf '*\n!.gitignore\n' >"$DIR/.gitignore"

for user in "${logins[@]}"; do
  [[ $user =~ ^[A-Za-z0-9_.-]+$ ]] || { echo "bad login name: $user" >&2; exit 2; }
  file=$DIR/$user.password
  if [[ ! -s $file ]]; then
    # 32 random bytes, base64url without padding: 43 characters, no ':' (the users file's separator)
    head -c 32 /dev/urandom | base64 | tr '+/' '-_' | tr -d '=\n' >"$file"
    echo "new password for $user in $file"
  fi
  if [[ $user == gateway-* && $(id -u) -eq 0 ]]; then
    chown "$GATEWAY_UID:$GATEWAY_UID" "$file"
  fi
done

# users.txt: every login that has a password file
: >"$DIR/users.txt.new"
for file in "$DIR"/*.password; do
  user=$(basename "$file" .password)
  printf '%s:%s\n' "$user" "$(cat "$file")" >>"$DIR/users.txt.new"
done
mv "$DIR/users.txt.new" "$DIR/users.txt"
echo "wrote $DIR/users.txt ($(wc -l <"$DIR/users.txt") logins)"
if [[ $(id -u) -ne 0 ]]; then
  echo "note: not root: give the gateways' password files to user $GATEWAY_UID before" \
    "'docker compose up' (chown $GATEWAY_UID $DIR/gateway-*.password)" >&2
fi
