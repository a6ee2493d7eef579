import sys
def crc(b):
    c=0xFFFF
    for x in b:
        c^=x
        for _ in range(8):
            c = (c>>1)^0xA001 if c&1 else c>>1
    return c
for line in sys.stdin:
    line=line.strip()
    if not line: continue
    h=line.replace(' ','')
    b=bytes.fromhex(h)
    c=crc(b[:-2])
    ok = b[-2]==(c&0xff) and b[-1]==(c>>8)
    print(("OK " if ok else "BAD"), line, "" if ok else "correct=%02X %02X"%(c&0xff,c>>8))
