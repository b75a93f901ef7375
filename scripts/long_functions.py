#!/usr/bin/env python3
"""Lists the non-test Rust functions longer than LIMIT lines, longest first.

    scripts/long_functions.py LIMIT DIR...      e.g. scripts/long_functions.py 100 core/src host-sim/src

A function's length runs from its `fn` line to its closing brace. Items under `#[cfg(test)]`
or `#[test]` are left out; comments, strings and character literals are skipped when braces
are matched. Exits 1 when any function is longer than LIMIT, else 0.
"""
import os
import re
import sys

def strip(src):
    # replace comments, strings, chars with spaces (keep newlines)
    out=[];i=0;n=len(src)
    while i<n:
        c=src[i]
        if src.startswith('//',i):
            j=src.find('\n',i); j=n if j<0 else j
            out.append(' '*(j-i)); i=j; continue
        if src.startswith('/*',i):
            depth=1;j=i+2
            while j<n and depth:
                if src.startswith('/*',j): depth+=1;j+=2
                elif src.startswith('*/',j): depth-=1;j+=2
                else: j+=1
            out.append(re.sub(r'[^\n]',' ',src[i:j])); i=j; continue
        m=re.match(r'b?r(#*)"',src[i:i+10]) if c in 'rb' and (i==0 or not (src[i-1].isalnum() or src[i-1]=='_')) else None
        if m:
            close='"'+m.group(1); j=src.find(close,i+m.end()); j=n if j<0 else j+len(close)
            out.append(re.sub(r'[^\n]',' ',src[i:j])); i=j; continue
        if c=='"' :
            j=i+1
            while j<n and src[j]!='"':
                j+= 2 if src[j]=='\\' else 1
            j+=1
            out.append(re.sub(r'[^\n]',' ',src[i:j])); i=j; continue
        if c=="'":
            m=re.match(r"'(\\(x..|u\{[0-9a-fA-F]+\}|.)|[^\\'])'",src[i:i+12])
            if m:
                out.append(' '*m.end()); i+=m.end(); continue
        out.append(c); i+=1
    return ''.join(out)

def scan(path, limit):
    src=open(path,encoding='utf-8').read()
    s=strip(src)
    lines=s.split('\n')
    res=[]
    # find test regions: #[cfg(test)] followed by item; mark its brace span
    def brace_end(pos):
        d=0
        for k in range(pos,len(s)):
            if s[k]=='{': d+=1
            elif s[k]=='}':
                d-=1
                if d==0: return k
            elif s[k]==';' and d==0: return k
        return len(s)-1
    test=[]
    for m in re.finditer(r'#\[(cfg\(test\)|test)\]',s):
        test.append((m.start(),brace_end(m.end())))
    for m in re.finditer(r'\bfn\s+([A-Za-z_][A-Za-z0-9_]*)',s):
        st=m.start()
        if any(a<=st<=b for a,b in test): continue
        # find body start: first '{' or ';' at paren depth 0 after signature
        k=m.end();p=0
        while k<len(s):
            ch=s[k]
            if ch in '([<' : p+=1
            elif ch in ')]>' : p-=1
            elif ch=='{' and p<=0: break
            elif ch==';' and p<=0: k=-1;break
            k+=1
        if k<0 or k>=len(s): continue
        e=brace_end(k)
        l0=s.count('\n',0,st)+1; l1=s.count('\n',0,e)+1
        ln=l1-l0+1
        if ln>limit: res.append((ln,path,l0,m.group(1)))
    return res

if len(sys.argv) < 3 or not sys.argv[1].isdigit():
    sys.exit("usage: long_functions.py LIMIT DIR...")
limit=int(sys.argv[1]); out=[]
for root in sys.argv[2:]:
    for dp,dn,fn in os.walk(root):
        for f in fn:
            if f.endswith('.rs'): out+=scan(os.path.join(dp,f),limit)
for ln,p,l0,name in sorted(out,reverse=True):
    print(f"{ln:5d} {p}:{l0} {name}")
sys.exit(1 if out else 0)
