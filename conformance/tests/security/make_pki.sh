#!/usr/bin/env bash
# A throwaway test PKI for Modbus/TCP Security, made with OpenSSL at test time
# in the build tree (never committed): make_pki.sh DIR
#
#   ca.crt/.key               the test CA
#   server.crt/.key           signed by it; SAN IP:127.0.0.1, DNS:localhost
#   server-wrong-host.crt     signed by it; names only wrong-host.invalid
#   server-untrusted.crt      signed by another CA (rogue-ca)
#   server-expired.crt        signed by the CA, validity in 2020
#   operator.crt, viewer.crt  client certificates with one role each (UTF8String)
#   no-role.crt               a client certificate without the role extension
#   two-roles.crt             the role extension holds two UTF8Strings
#   printable-role.crt        the role as a PrintableString
#   expired.crt               role operator, validity in 2020
#   untrusted.crt             role operator, signed by rogue-ca
#   server-v1.crt             an X.509 version 1 server certificate (CN localhost)
#   client-v1.crt             an X.509 version 1 client certificate, signed by the CA
# Every key is mode 600. The role extension is MB-TCP-Security v2.1 §8.3's:
# OID 1.3.6.1.4.1.50316.802.1, an ASN.1 UTF8String.
set -euo pipefail
dir=$1
mkdir -p "$dir"
cd "$dir"
umask 077
role_oid=1.3.6.1.4.1.50316.802.1

key() { openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$1.key" 2>/dev/null; }

cat > ext.cnf <<CNF
[ca]
basicConstraints = critical,CA:TRUE
keyUsage = critical,keyCertSign,cRLSign
subjectKeyIdentifier = hash
[server]
basicConstraints = CA:FALSE
keyUsage = critical,digitalSignature
extendedKeyUsage = serverAuth
subjectAltName = IP:127.0.0.1,DNS:localhost
[wrong_host]
basicConstraints = CA:FALSE
extendedKeyUsage = serverAuth
subjectAltName = DNS:wrong-host.invalid
[operator]
basicConstraints = CA:FALSE
extendedKeyUsage = clientAuth
$role_oid = ASN1:UTF8String:operator
[viewer]
basicConstraints = CA:FALSE
extendedKeyUsage = clientAuth
$role_oid = ASN1:UTF8String:viewer
[no_role]
basicConstraints = CA:FALSE
extendedKeyUsage = clientAuth
[two_roles]
basicConstraints = CA:FALSE
extendedKeyUsage = clientAuth
$role_oid = ASN1:SEQUENCE:two_roles_seq
[two_roles_seq]
r1 = UTF8String:operator
r2 = UTF8String:viewer
[printable_role]
basicConstraints = CA:FALSE
extendedKeyUsage = clientAuth
$role_oid = ASN1:PRINTABLESTRING:operator
CNF

ca() {  # ca NAME SUBJECT
  key "$1"
  openssl req -new -x509 -key "$1.key" -subj "/CN=$2" -days 30 -extensions ca -config ext.cnf -out "$1.crt" 2>/dev/null ||
    openssl req -new -x509 -key "$1.key" -subj "/CN=$2" -days 30 -addext basicConstraints=critical,CA:TRUE -out "$1.crt"
}
leaf() {  # leaf NAME SUBJECT EXTSECTION [CA]
  local issuer=${4:-ca}
  key "$1"
  openssl req -new -key "$1.key" -subj "/CN=$2" -out "$1.csr" 2>/dev/null
  openssl x509 -req -in "$1.csr" -CA "$issuer.crt" -CAkey "$issuer.key" -CAcreateserial -days 30 \
    -extfile ext.cnf -extensions "$3" -out "$1.crt" 2>/dev/null
  rm -f "$1.csr"
}
# A certificate whose validity ended in 2020, through `openssl ca` (the only
# OpenSSL 3.0 command that takes explicit dates).
expired() {  # expired NAME SUBJECT EXTSECTION
  key "$1"
  openssl req -new -key "$1.key" -subj "/CN=$2" -out "$1.csr" 2>/dev/null
  mkdir -p ca-db && : > ca-db/index.txt && echo 1000 > ca-db/serial
  cat > ca-db/ca.cnf <<CNF
[ca]
default_ca = test
[test]
database = ca-db/index.txt
serial = ca-db/serial
new_certs_dir = ca-db
default_md = sha256
policy = any
unique_subject = no
[any]
commonName = supplied
CNF
  openssl ca -batch -config ca-db/ca.cnf -cert ca.crt -keyfile ca.key -in "$1.csr" -out "$1.crt" \
    -startdate 20200101000000Z -enddate 20200201000000Z -extfile ext.cnf -extensions "$3" -notext 2>/dev/null
  rm -f "$1.csr"
}

ca ca "mbconform test CA"
ca rogue-ca "mbconform rogue CA"
leaf server "mbconform test server" server
leaf server-wrong-host "wrong-host.invalid" wrong_host
leaf server-untrusted "mbconform untrusted server" server rogue-ca
expired server-expired "mbconform expired server" server
# An X.509 version 1 server certificate: `openssl x509 -req` without
# extensions writes no version 3 field (no SAN either, so its name is the CN,
# localhost, which OpenSSL's host check reads when there is no SAN).
key server-v1
openssl req -new -key server-v1.key -subj "/CN=localhost" -out server-v1.csr 2>/dev/null
openssl x509 -req -in server-v1.csr -CA ca.crt -CAkey ca.key -CAcreateserial -days 30 -out server-v1.crt 2>/dev/null
rm -f server-v1.csr
# An X.509 version 1 client certificate signed by the CA (so no role
# extension either: a v1 certificate has no extensions).
key client-v1
openssl req -new -key client-v1.key -subj "/CN=client v1" -out client-v1.csr 2>/dev/null
openssl x509 -req -in client-v1.csr -CA ca.crt -CAkey ca.key -CAcreateserial -days 30 -out client-v1.crt 2>/dev/null
rm -f client-v1.csr
leaf operator "operator client" operator
leaf viewer "viewer client" viewer
leaf no-role "client without a role" no_role
leaf two-roles "client with two roles" two_roles
leaf printable-role "client with a PrintableString role" printable_role
leaf untrusted "untrusted client" operator rogue-ca
expired expired "expired client" operator
rm -rf ca-db ext.cnf ./*.srl
chmod 600 ./*.key
cat > roles.yaml <<YAML
mbconform_roles: 1
roles:
  viewer:
    - functions: [1, 2, 3, 4]
  operator:
    - functions: [1, 2, 3, 4, 43]
    - functions: [5, 6, 15, 16]
      addresses: [0-99]
YAML
